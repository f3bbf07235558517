"""One constraint model per demonstration (e.g. a constant constraint that changes from
one demonstration to the next, ALGORITHMS.md §3.5 with the varying-constraint tutorial)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.base import clone
from ccl_cli.learn.constraint.base import ConstraintModel


class PerDemonstration(ConstraintModel):
    """Fit a copy of ``estimator`` on each demonstration separately.

    ``fit(X, U, groups=...)`` takes the demonstration id of each sample; without
    ``groups`` the data are one demonstration. Predicting needs the demonstration id of
    each sample (one of those seen in ``fit``), except when a single demonstration was
    fitted.

    Attributes:
        models_: dict demo id → fitted estimator. n_constraints_: the most common count;
        selection_, n_features_in_.
    """

    needs_demo = True
    _parameter_constraints: ClassVar[dict[str, list]] = {"estimator": [ConstraintModel]}
    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "selection_": "value", "models_": "models"}

    def __init__(self, estimator: ConstraintModel) -> None:  # the one positional parameter
        self._store_params(locals())

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None) -> PerDemonstration:
        X, U = self._prepare_fit(X, U)
        groups = np.zeros(len(U), int) if groups is None else np.asarray(groups)
        self.models_: dict[int, Any] = {}
        for d in np.unique(groups):  # loop over demonstrations, not samples
            m = groups == d
            self.models_[int(d)] = clone(self.estimator).fit(X[m], U[m])
        counts = [m.n_constraints_ for m in self.models_.values()]
        self.n_constraints_ = int(np.bincount(counts).argmax())
        self.selection_ = {"rule": "per-demonstration",
                           "n_constraints": self.n_constraints_,
                           "per_demo": {int(k): int(m.n_constraints_) for k, m in self.models_.items()},
                           "reason": "most common count over demonstrations"}
        return self

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        """Ñ(X) of each sample's own demonstration: (N, p), groups (N,) → (N, q, q)."""
        self._check_fitted("models_")
        X = self._check_states(X)
        if groups is None:
            if len(self.models_) > 1:
                raise InputError("a per-demonstration constraint model needs the demonstration ids")
            groups = np.full(len(X), next(iter(self.models_)))
        groups = np.asarray(groups)
        q = next(iter(self.models_.values())).n_action_
        out = np.empty((X.shape[0], q, q))
        for d in np.unique(groups):
            if int(d) not in self.models_:
                raise InputError(f"demonstration {int(d)} was not seen when fitting this model")
            m = groups == d
            out[m] = self.models_[int(d)].projection(X[m])
        return out

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        raise InputError("per-demonstration models may differ in s; use projection()")
