"""The interface every learnt constraint shares (ALGORITHMS.md §1, §3)."""

from __future__ import annotations

import numpy as np

from ccl_cli.learn.base import Estimator
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.linalg import nullspace_projection


class ConstraintModel(Estimator):
    """A learnt constraint. Subclasses implement :meth:`constraint` (and may give a
    cheaper :meth:`projection`).

    Attributes (after ``fit``): ``n_constraints_``, ``selection_`` (dict with the rule,
    the residuals it looked at and why it chose ``n_constraints_``), ``n_features_in_``.
    """

    #: True when the model needs the demonstration id of each sample to predict.
    needs_demo = False

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        """Ã(X): (N, p) → (N, s, q)."""
        raise NotImplementedError

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        """Ñ(X) = I − Ã⁺Ã: (N, p) → (N, q, q) (ALGORITHMS.md §1)."""
        self._check_fitted("n_constraints_")
        return nullspace_projection(self.constraint(X, groups=groups))

    def score(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None) -> float:
        """−NPOE of actions U (N, q) at states X (N, p) (§6): −mean ‖u − Ñ(x)u‖² / Σ var(u);
        higher is better, 0 when every action lies in the learnt null space."""
        return -npoe_error(self.projection(X, groups=groups), np.asarray(U, dtype=float))
