"""Learning the unconstrained null-space policy π (ALGORITHMS.md §5; u = w, b = 0).

All learners minimise a least-squares criterion that is linear in the weights, so
each is solved in closed form (batched over samples, no iteration):

* ``pi`` — inconsistency error Σ_n (û_nᵀ π̃(x_n) − ‖u_n‖)², π̃(x) = Wᵀβ(x)
  (Howard et al. 2009); rows kron(β_n, û_n), eigen pseudo-inverse (cut-off 1e-6 relative to
  the largest eigenvalue; the original library's is absolute: ``cutoff_rule="absolute"``).
* ``pi-weighted`` — the same residual times ‖u_n‖: u_nᵀ π̃(x_n) = ‖u_n‖², so samples
  at the noise level (random û) no longer get full weight.
* ``pi-coupled`` — with projections Ñ_n (true or learnt): u_n ≈ Ñ_n Wᵀ β(x_n), rows
  kron(β_nᵀ, Ñ_n) (Armesto et al.).
* ``lwpi`` — per centre c a local linear model W_cᵀ [x; 1] fitted to the inconsistency
  error with weights β_c(x_n); π̃(x) = Σ_c β_c(x) W_cᵀ φ(x) / Σ_c β_c(x).
* ``dpl`` — direct regression of u on β(x): the biased baseline.

Samples with ‖u_n‖ below ``min_norm`` carry no direction and are dropped.

Scale: every normal matrix is summed over blocks of ``chunk_size`` rows (default 8192)
with BLAS-shaped products, so temporaries are O(chunk · K q) whatever N (no N × K
feature matrix, no N × K q regressor matrix); predict works in the same blocks.
"""

from __future__ import annotations

from typing import ClassVar, get_args

import numpy as np

from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.learn.base import Estimator
from ccl_cli.learn.basis import BasisParams, RBFBasis, make_basis
from ccl_cli.learn.consistency import inconsistency_error
from ccl_cli.learn.defaults import POLICY_METHOD
from ccl_cli.learn.linalg import eigen_lstsq, kron_rows, row_chunks
from ccl_cli.learn.model_selection import Tunable
from ccl_cli.learn.params import CutoffRule, Interval, Options, SeedParams, parameters
from ccl_cli.learn.params import PolicyMethod as Method

METHODS = get_args(Method)


@parameters
class PolicyLearner(Tunable, Estimator, BasisParams, SeedParams):
    """π̃(x) = Wᵀ β(x) learnt by one of :data:`METHODS`.

    Args:
        method: ``pi`` (default), ``pi-weighted``, ``pi-coupled``, ``lwpi``, ``dpl``.
        basis, n_centres, seed: feature map (``lwpi`` needs an RBF basis).
        cutoff: eigenvalue cut-off of the pseudo-inverse: eigenvalues of the normal matrix
            below ``cutoff · λ_max`` are dropped (``cutoff_rule="relative"``, the default).
        cutoff_rule: ``relative`` or ``absolute`` — eigenvalues below ``cutoff`` itself are
            dropped: the original library's rule (absolute 1e-6). They are not the same rule:
            with the tutorial settings ``absolute`` reproduces the original's numbers (README
            "Reproducing the original library").
        min_norm: samples with ‖u‖ below this are dropped (not for ``dpl``/``pi-coupled``).
        chunk_size: rows per block of the normal-equation sums (default 8192).
        tune: choose the basis by cross-validation (:class:`ccl_cli.learn.model_selection.Tuned`;
            True by default, a dict ``{budget, grid, folds, max_rows}`` to adjust, False for
            the fixed settings). Grid: K ∈ {n_centres, 16, 49, 100} × σ² factors {1, ½, ¼}; for
            lwpi K ∈ {n_centres, 9, 16, 25, 49} × {1, ½, ¼, 0.1, 0.05}.

    Attributes:
        basis_, W_ ((K, q); for lwpi (K, p + 1, q)), n_used_, n_features_in_, tuning_.
    """

    _parameter_constraints: ClassVar[dict[str, list]] = {
        "method": [Options.of(Method)], "cutoff": [Interval(float, 0, None)],
        "min_norm": [Interval(float, 0, None)], "chunk_size": [Interval(int, 1, None), None],
        "cutoff_rule": [Options.of(CutoffRule)]}
    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_action_": "value", "n_used_": "value", "W_": "array", "basis_": "basis"}
    method: Method = POLICY_METHOD
    cutoff: float = 1e-6
    min_norm: float = 1e-6
    chunk_size: int | None = None
    cutoff_rule: CutoffRule = "relative"

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        if self.method == "lwpi":
            return [((self.n_centres, 9, 16, 25, 49), (1.0, 0.5, 0.25, 0.1, 0.05))]
        return [((self.n_centres, 16, 49, 100), (1.0, 0.5, 0.25))]

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            projections: np.ndarray | None = None) -> PolicyLearner:
        """Fit on states X (N, p), actions U (N, q); ``pi-coupled`` needs ``projections``
        Ñ_n (N, q, q) (true, or from a learnt constraint model). ``groups`` (N,):
        demonstration ids, only for the folds of tuning."""
        X, U = self._prepare_fit(X, U)
        if self._fit_tuned(X, U, groups=groups, projections=projections):
            return self
        absolute = self.cutoff_rule == "absolute"
        self.basis_ = make_basis(self.basis, self.n_centres, self.seed).fit(X)
        self.n_action_ = U.shape[1]
        norm = np.linalg.norm(U, axis=1)
        if self.method in ("pi", "pi-weighted", "lwpi"):
            keep = norm > self.min_norm
            if not keep.all():
                X, U, norm = X[keep], U[keep], norm[keep]
            if len(X) < 2:
                raise LearningError(f"fewer than 2 samples with ‖u‖ > {self.min_norm}")
        self.n_used_ = int(len(X))
        q = self.n_action_
        K = self.basis_.n_features
        P = None
        if self.method == "pi-coupled":
            if projections is None:
                raise InputError("pi-coupled needs the projections Ñ_n (true or learnt)")
            P = np.asarray(projections, dtype=float)
            if P.shape != (len(X), q, q):
                raise InputError(f"projections must be ({len(X)}, {q}, {q}), got {P.shape}")
        if self.method == "lwpi" and not isinstance(self.basis_, RBFBasis):
            raise ConfigError("lwpi needs an RBF basis (its centres weight the local models)")
        d = X.shape[1] + 1
        size = {"dpl": K, "lwpi": K * d * q}.get(self.method, K * q)
        M = np.zeros((K, d * q, d * q)) if self.method == "lwpi" else np.zeros((size, size))
        r = np.zeros((K, d * q) if self.method == "lwpi" else (size, q) if self.method == "dpl"
                     else size)
        for rows in row_chunks(len(X), self.chunk_size):
            B = self.basis_.transform(X[rows])
            Ub, nb = U[rows], norm[rows]
            if self.method == "dpl":
                M += B.T @ B
                r += B.T @ Ub
            elif self.method in ("pi", "pi-weighted"):
                # rows kron(β_n, û_n) (pi) or kron(β_n, u_n) (pi-weighted), target ‖u‖ or ‖u‖²
                R = kron_rows(B, Ub / nb[:, None] if self.method == "pi" else Ub)
                M += R.T @ R
                r += R.T @ (nb if self.method == "pi" else nb**2)
            elif self.method == "pi-coupled":
                # rows Ñ_n [β_1 I, ..., β_K I] (q, K q): M = Σ_n kron(β_n β_nᵀ, Ñ_nᵀÑ_n),
                # one BLAS product per (i, j) entry; r = Σ_n β_n ⊗ Ñ_nᵀ u_n
                Pb = P[rows]
                G = np.einsum("nai,naj->nij", Pb, Pb, optimize=True)
                M4 = M.reshape(K, q, K, q)
                for i in range(q):  # loops over action dimensions, not samples
                    for j in range(q):
                        M4[:, i, :, j] += (B * G[:, i, j, None]).T @ B
                r += (B.T @ np.einsum("nai,na->ni", Pb, Ub, optimize=True)).ravel()
            else:  # lwpi: per centre c, Σ_n β_c(x_n) R_n R_nᵀ with rows R_n = φ_n ⊗ û_n
                phi = np.hstack([X[rows], np.ones((len(B), 1))])
                R = kron_rows(phi, Ub / nb[:, None])
                D = R.shape[1]
                M += (B.T @ (R[:, :, None] * R[:, None, :]).reshape(len(B), D * D)).reshape(K, D, D)
                r += B.T @ (R * nb[:, None])
        if self.method == "dpl":
            self.W_ = eigen_lstsq(M, r.T, self.cutoff, absolute).T
        elif self.method == "lwpi":
            self.W_ = eigen_lstsq(M, r, self.cutoff, absolute).reshape(K, d, q)
        else:
            self.W_ = eigen_lstsq(M, r, self.cutoff, absolute).reshape(K, q)
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        """π̃(X): (N, p) → (N, q)."""
        self._check_fitted("W_")
        X = self._check_states(X)
        out = np.empty((len(X), self.n_action_))
        for rows in row_chunks(len(X), self.chunk_size):
            B = self.basis_.transform(X[rows])
            if self.method == "lwpi":  # Σ_c β_c W_cᵀ φ (β rows sum to 1)
                phi = np.hstack([X[rows], np.ones((len(B), 1))])
                local = (B @ self.W_.reshape(len(self.W_), -1)).reshape(len(B), phi.shape[1], -1)
                out[rows] = np.einsum("ni,niq->nq", phi, local)
            else:
                out[rows] = B @ self.W_
        return out

    def score(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
              projections: np.ndarray | None = None) -> float:
        """Minus the normalised inconsistency error (§5) of π̃ on actions U (N, q) at states
        X (N, p): −mean ‖u − ûûᵀπ̃(x)‖² / Σ var(u) (pi-weighted: terms weighted by ‖u‖²);
        pi-coupled with ``projections`` Ñ (N, q, q): −mean ‖u − Ñπ̃(x)‖² / Σ var(u). Higher is better."""
        P = self.predict(X)
        U = np.asarray(U, dtype=float)
        if self.method == "pi-coupled":
            return -inconsistency_error(P, U, projections)
        return -inconsistency_error(P, U, weighted=self.method == "pi-weighted")
