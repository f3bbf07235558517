"""Learning the null-space component w ("ncl", ALGORITHMS.md §4).

Model w̃(x) = W β(x), W ∈ R^{q×K}. Since N u = w and v ⟂ w, a consistent model equals
the projection of u onto itself: minimise E[w̃] = Σ_n ‖P̃_n u_n − w̃_n‖², with
P̃_n = w̃_n w̃_nᵀ / ‖w̃_n‖². With a = u_nᵀ w̃_n and c = ‖w̃_n‖², the residual norm is
|a − c| / √c; as in the original the scalar residual r_n = (a − c + 1e-8) / √c is
minimised by Levenberg–Marquardt with its analytic Jacobian

    ∂r_n/∂W = [ (u_n − 2 w̃_n) / √c − (a − c + 1e-8) w̃_n / c^{3/2} ] β_nᵀ,

started from ordinary least squares of U on β (eigen-decomposition pseudo-inverse,
eigenvalues below 1e-8 of the largest dropped).
"""

from __future__ import annotations

import numpy as np
from scipy.optimize import least_squares

from ccl_cli.basis import Basis, make_basis
from ccl_cli.constraint.base import check_xu
from ccl_cli.estimator import Estimator
from ccl_cli.linalg import eigen_lstsq
from ccl_cli.selection import TUNE, basis_grid, rbf_tunable

EPS_RESIDUAL = 1e-8


class NullSpaceComponent(Estimator):
    """Learns w̃(x) = W β(x) from observations u = v + w.

    Args:
        basis, n_centres, seed: feature map (normalised RBF by default).
        max_iter: LM iterations (function evaluations) at most (original: 1000).
        tol: LM tolerances (original: 1e-9).
        tune: choose the basis by cross-validation (:func:`ccl_cli.selection.tune`; True by
            default, a dict ``{budget, grid, folds}`` to adjust, False for the fixed settings).

    Attributes:
        basis_, W_ (q, K), cost_ (final Σ r²), n_iter_.
    """

    def __init__(
        self,
        *,
        basis: str | dict | Basis | None = "rbf",
        n_centres: int = 16,
        seed: int = 0,
        max_iter: int = 1000,
        tol: float = 1e-9,
        tune: bool | dict = TUNE,
    ) -> None:
        self.basis = basis
        self.n_centres = n_centres
        self.seed = seed
        self.max_iter = max_iter
        self.tol = tol
        self.tune = tune

    def _tune_grid(self, X: np.ndarray, U: np.ndarray) -> dict[str, list]:
        if not rbf_tunable(self.basis):
            return {}
        return {"basis": basis_grid(X, (self.n_centres, 16, 36, 64, 100), (1.0, 0.5), self.seed)}

    def fit(self, X: np.ndarray, U: np.ndarray, demo: np.ndarray | None = None
            ) -> NullSpaceComponent:
        X, U = check_xu(X, U)
        self._set_n_features(X)
        if self._fit_tuned(X, U, demo=demo):
            return self
        self.basis_ = make_basis(self.basis, self.n_centres, self.seed).fit(X)
        B = self.basis_.transform(X)
        n, K = B.shape
        q = U.shape[1]
        W0 = eigen_lstsq(B.T @ B, (B.T @ U).T, 1e-8).T  # (K, q) → OLS start
        W0 = np.linalg.lstsq(B, U, rcond=None)[0] if not np.isfinite(W0).all() else W0

        def parts(w: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
            Wt = B @ w.reshape(q, K).T  # (N, q)
            a = np.einsum("nq,nq->n", U, Wt)
            c = np.maximum(np.einsum("nq,nq->n", Wt, Wt), 1e-300)
            return Wt, a, c

        def residual(w: np.ndarray) -> np.ndarray:
            _, a, c = parts(w)
            return (a - c + EPS_RESIDUAL) / np.sqrt(c)

        def jacobian(w: np.ndarray) -> np.ndarray:
            Wt, a, c = parts(w)
            sc = np.sqrt(c)[:, None]
            g = (U - 2.0 * Wt) / sc - ((a - c + EPS_RESIDUAL)[:, None] * Wt) / (sc**3)
            return (g[:, :, None] * B[:, None, :]).reshape(n, q * K)

        method = "lm" if n >= q * K else "trf"
        sol = least_squares(residual, W0.T.ravel(), jac=jacobian, method=method,
                            xtol=self.tol, ftol=self.tol, gtol=self.tol, max_nfev=self.max_iter)
        self.W_ = sol.x.reshape(q, K)
        self.cost_ = 2.0 * float(sol.cost)
        self.n_iter_ = int(sol.nfev)
        self.n_action_ = q
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        """w̃(X) = W β(X): (N, p) → (N, q)."""
        self._check_fitted("W_")
        return self.basis_.transform(np.asarray(X, dtype=float)) @ self.W_.T

    def task_component(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """ṽ = u − w̃(x): (N, q)."""
        return np.asarray(U, dtype=float) - self.predict(X)
