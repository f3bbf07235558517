"""Common interface of constraint models and per-demonstration fitting."""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.base import Estimator, clone
from ccl_cli.learn.linalg import nullspace_projection


class ConstraintModel(Estimator):
    """A learnt constraint. Subclasses implement :meth:`constraint`.

    Attributes (after ``fit``): ``n_constraints_``, ``selection_`` (dict with the rule,
    the residuals it looked at and why it chose ``n_constraints_``).
    """

    #: True when the model needs the demonstration id of each sample to predict.
    needs_demo = False

    def constraint(self, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
        """Ã(X): (N, p) → (N, s, q)."""
        raise NotImplementedError

    def projection(self, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
        """Ñ(X) = I − Ã⁺Ã: (N, p) → (N, q, q) (ALGORITHMS.md §1)."""
        self._check_fitted("n_constraints_")
        return nullspace_projection(self.constraint(X, demo))


def check_xu(X: np.ndarray, U: np.ndarray, min_samples: int = 2) -> tuple[np.ndarray, np.ndarray]:
    X = np.asarray(X, dtype=float)
    U = np.asarray(U, dtype=float)
    if X.ndim != 2 or U.ndim != 2 or X.shape[0] != U.shape[0]:
        raise InputError(f"X and U must be (N, p) and (N, q) with the same N, got {X.shape}, {U.shape}")
    if X.shape[0] < min_samples:
        raise InputError(f"need at least {min_samples} samples, got {X.shape[0]}")
    if not (np.isfinite(X).all() and np.isfinite(U).all()):
        raise InputError("X or U contains NaN or inf")
    return X, U


class PerDemonstration(ConstraintModel):
    """Fit a copy of ``estimator`` on each demonstration separately.

    Predicting needs the demonstration id of each sample (one of those seen in ``fit``).

    Attributes:
        models_: dict demo id → fitted estimator.
    """

    needs_demo = True

    def __init__(self, estimator: ConstraintModel) -> None:  # the one positional parameter
        self.estimator = estimator

    def fit(self, X: np.ndarray, U: np.ndarray, demo: np.ndarray) -> PerDemonstration:
        X, U = check_xu(X, U)
        self._set_n_features(X)
        demo = np.asarray(demo)
        self.models_: dict[int, Any] = {}
        for d in np.unique(demo):  # loop over demonstrations, not samples
            m = demo == d
            self.models_[int(d)] = clone(self.estimator).fit(X[m], U[m])
        counts = [m.n_constraints_ for m in self.models_.values()]
        self.n_constraints_ = int(np.bincount(counts).argmax())
        self.selection_ = {"rule": "per-demonstration",
                           "n_constraints": self.n_constraints_,
                           "per_demo": {int(k): int(m.n_constraints_) for k, m in self.models_.items()},
                           "reason": "most common count over demonstrations"}
        return self

    def projection(self, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
        self._check_fitted("models_")
        if demo is None:
            raise InputError("a per-demonstration constraint model needs the demonstration ids")
        demo = np.asarray(demo)
        X = np.asarray(X, dtype=float)
        q = next(iter(self.models_.values())).n_action_
        out = np.empty((X.shape[0], q, q))
        for d in np.unique(demo):
            if int(d) not in self.models_:
                raise InputError(f"demonstration {int(d)} was not seen when fitting this model")
            m = demo == d
            out[m] = self.models_[int(d)].projection(X[m])
        return out

    def constraint(self, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
        raise InputError("per-demonstration models may differ in s; use projection()")
