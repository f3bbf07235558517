"""No constraint: A has no rows, Ñ = I (k = 0; issue 17).

The answer when the motion along every candidate row is more than noise: free-space reaching,
handwriting on a tablet. Every action lies in the null space, so the NPOE is 0 by construction.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.learn.constraint.base import ConstraintModel
from ccl_cli.learn.params import parameters

#: What a model without rows says.
NO_CONSTRAINT = "no constraint: the motion along every direction is more than the noise"


@parameters
class NoConstraint(ConstraintModel):
    """The constraint with no rows: Ã (N, 0, q), Ñ = I.

    Attributes: n_constraints_ (0), n_action_ (q), selection_, n_features_in_.
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value"}

    varies_with_state = False

    def fit(self, X: np.ndarray | None, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None) -> NoConstraint:
        """Record q from U (N, q) (and p from X (N, p), which may be None); nothing else is read."""
        X, U = self._prepare_fit(X, U)
        self.n_action_ = int(U.shape[1])
        self.n_constraints_ = 0
        self.selection_ = {"rule": "fixed", "n_constraints": 0, "values": [], "criterion": "",
                           "reason": NO_CONSTRAINT}
        return self

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã with no rows: (N, 0, q)."""
        self._check_fitted("n_action_")
        return np.zeros((self._check_states(X).shape[0], 0, self.n_action_))

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ñ = I: (N, q, q)."""
        self._check_fitted("n_action_")
        X = self._check_states(X)
        return np.broadcast_to(np.eye(self.n_action_), (X.shape[0], self.n_action_, self.n_action_)).copy()
