"""State-dependent constraint A(x) = Λ(x) Φ(x) with known features ("lambda", §3.3).

Φ(x) ∈ R^{r×q} is known (typically the task Jacobian); only the selection Λ(x),
orthonormal rows in R^r, is learnt, on v_n = Φ(x_n) u_n (samples with ‖v_n‖ < 1e-3
carry no information and are dropped), by the same sequential angle search as alpha.
Prediction: A = ΛΦ, Ñ = I − A⁺A.
"""

from __future__ import annotations

from collections.abc import Callable
from math import isqrt

import numpy as np

from ccl_cli.errors import ConfigError, LearningError
from ccl_cli.learn.basis import Basis, make_basis
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.alpha import AngularConstraintMixin
from ccl_cli.learn.constraint.angular import MAX_ITER, chunked_features, rows_from_weights
from ccl_cli.learn.constraint.base import ConstraintModel, check_xu
from ccl_cli.learn.kinematics import ArmFeatures
from ccl_cli.learn.linalg import nullspace_projection
from ccl_cli.learn.model_selection import TUNE, basis_grid, rbf_tunable

Features = Callable[[np.ndarray], np.ndarray]
#: ‖Φu‖ below this carries no information about Λ.
MIN_TASK_NORM = 1e-3


def make_features(spec: str | dict | Features) -> Features:
    """Φ from a callable (X (N, p) → (N, r, q)) or a built-in arm: ``"arm2"``,
    ``"arm7"``, or ``{"arm": "arm7", "rows": [0, 1, 2]}``."""
    if callable(spec):
        return spec
    if isinstance(spec, str):
        spec = {"arm": spec}
    if isinstance(spec, dict) and "arm" in spec:
        try:
            return ArmFeatures(spec["arm"], spec.get("rows"))
        except ValueError as exc:
            raise ConfigError(str(exc)) from exc
    raise ConfigError(f"features must be a callable or a built-in arm (arm2, arm7), got {spec!r}")


class KnownFeatureConstraint(AngularConstraintMixin, ConstraintModel):
    """Ã(x) = Λ̃(x) Φ(x) with Λ̃ rows a(W_k β(x)) in R^r.

    Args:
        features: Φ — a callable X → (N, r, q), or a built-in arm name/spec.
        Other arguments (``tune`` too) as :class:`~ccl_cli.learn.constraint.alpha.StateDependentConstraint`.

    Attributes:
        basis_, weights_, n_constraints_, nmse_, selection_, n_dropped_.
    """

    def __init__(
        self,
        *,
        features: str | dict | Features = "arm2",
        basis: str | dict | Basis | None = "rbf",
        n_centres: int = 16,
        selection: str = sel.DEFAULT_RULE,
        n_constraints: int | None = None,
        max_constraints: int | None = None,
        n_restarts: int = 3,
        seed: int = 0,
        max_iter: int = MAX_ITER,
        tol: float = 1e-9,
        gap_floor: float = 1e-9,
        cv_folds: int = 5,
        tune: bool | dict = TUNE,
    ) -> None:
        self.features = features
        self.basis = basis
        self.n_centres = n_centres
        self.selection = selection
        self.n_constraints = n_constraints
        self.max_constraints = max_constraints
        self.n_restarts = n_restarts
        self.seed = seed
        self.max_iter = max_iter
        self.tol = tol
        self.gap_floor = gap_floor
        self.cv_folds = cv_folds
        self.tune = tune

    def _tune_grid(self, X: np.ndarray, U: np.ndarray) -> dict[str, list]:
        """The configured K centres and the next square number of centres, (⌊√K⌋ + 1)²
        (16 → 25, 1 → 4), default widths, k-means-placed.

        Measured (issue 9; two-link arm, test NPPE, median of seeds 0–4): 3.2e-7 untuned
        (16) → 1.7e-9 tuned (25 chosen in 5/5 seeds; fit 0.02 → 0.16 s; held-out NPOE falls
        with the test error all the way to 36 centres, but a 36-centre CV took ~4 s);
        wider bases (σ² × 2) gain < 2× at 2–8× the time. On the 7-DoF arm with one centre
        the grid is {1, 4} and held-out NPOE (by demonstration) keeps the one centre when
        more do not generalise."""
        if not rbf_tunable(self.basis):
            return {}
        k = int(self.n_centres)
        grid = basis_grid(X, (k, (isqrt(k) + 1) ** 2), (1.0,), self.seed)
        return {"basis": grid} if grid else {}  # too few samples for any candidate: fit as given

    def fit(self, X: np.ndarray, U: np.ndarray, demo: np.ndarray | None = None
            ) -> KnownFeatureConstraint:
        X, U = check_xu(X, U)
        self._set_n_features(X)
        if self._fit_tuned(X, U, demo=demo):
            return self
        self.features_ = make_features(self.features)
        Phi = self.features_(X)
        if Phi.ndim != 3 or Phi.shape[0] != X.shape[0] or Phi.shape[2] != U.shape[1]:
            raise ConfigError(f"features must give (N, r, {U.shape[1]}) matrices, got {Phi.shape}")
        V = np.einsum("nrq,nq->nr", Phi, U)
        keep = np.linalg.norm(V, axis=1) >= MIN_TASK_NORM
        self.n_dropped_ = int((~keep).sum())
        if keep.sum() < 2:
            raise LearningError(f"only {int(keep.sum())} samples have ‖Φu‖ ≥ {MIN_TASK_NORM}")
        X_all = X
        demo_all = np.zeros(len(X), int) if demo is None else np.asarray(demo)
        X, V = X[keep], V[keep]
        demo = demo_all[keep]
        self.n_action_ = U.shape[1]
        self.n_task_ = V.shape[1]
        self.basis_ = make_basis(self.basis, self.n_centres, self.seed).fit(X)
        B = chunked_features(self.basis_, X)
        self._X, self._U, self._demo = X_all, U, demo_all
        self._learn_rows(B, V, X, demo)
        del self._X, self._U, self._demo
        return self

    def projection_k(self, X: np.ndarray, k: int) -> np.ndarray:
        """Ñ(X) of the first ``k`` learnt rows (the rows are nested): (N, p) → (N, q, q)."""
        self._check_fitted("weights_")
        X = np.asarray(X, dtype=float)
        lam = rows_from_weights(self.basis_.transform(X), self.weights_[:k], self.n_task_)
        return nullspace_projection(np.einsum("nkr,nrq->nkq", lam, self.features_(X)))

    def selection_matrix(self, X: np.ndarray) -> np.ndarray:
        """Λ̃(X): (N, s, r)."""
        self._check_fitted("weights_")
        return rows_from_weights(self.basis_.transform(X), self.weights_, self.n_task_)

    def constraint(self, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
        """Ã(X) = Λ̃(X) Φ(X): (N, s, q)."""
        X = np.asarray(X, dtype=float)
        return np.einsum("nkr,nrq->nkq", self.selection_matrix(X), self.features_(X))
