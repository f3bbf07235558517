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

Samples with ‖u_n‖ below ``min_norm`` carry no direction and are dropped (lwpi's search also
tries floors at the noise level, :data:`NOISE_FRACTIONS`).

Scale: every normal matrix is summed over blocks of ``chunk_size`` rows (default 8192)
with BLAS-shaped products, so temporaries are O(chunk · K q) whatever N (no N × K
feature matrix, no N × K q regressor matrix); predict works in the same blocks.
"""

from __future__ import annotations

from functools import partial
from typing import Any, ClassVar, get_args

import numpy as np

from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.learn.base import Estimator, clone
from ccl_cli.learn.basis import Basis, BasisParams, RBFBasis, feature_cache_bytes
from ccl_cli.learn.blocksums import block_sums
from ccl_cli.learn.consistency import inconsistency_error
from ccl_cli.learn.defaults import POLICY_METHOD
from ccl_cli.learn.linalg import CHUNK_ROWS, eigen_solve, kron_rows, row_chunks
from ccl_cli.learn.model_selection import WIDTH, Folds, Tunable, basis_grid, held_out_errors
from ccl_cli.learn.params import ChunkSize, CutoffRule, NonNegative, SeedParams, parameters
from ccl_cli.learn.params import PolicyMethod as Method

METHODS = get_args(Method)
#: Cut-offs a default search tries besides the configured one (docs/measurements.md, "pi and lwpi").
CUTOFFS = (1e-9, 1e-12)
#: pi searches states of at most this many dimensions with RBF centres on a grid over the data's box
#: (k-means above): the held-out error cannot tell the two apart, and grid centres generalise to
#: states between the demonstrations (docs/measurements.md, the original's table; measured for pi:
#: lwpi's narrow local models lost on noise-free limit cycles with them).
GRID_DIMS = 2
GRID_METHODS = ("pi",)
#: The searches of NOISE_METHODS also try ``min_norm`` = f · rms‖u‖ for these f (besides the
#: configured value): a sample whose ‖u‖ is at the noise level has a random direction û, yet the
#: inconsistency error (§5) gives it full weight (docs/measurements.md, "lwpi: samples at the noise level").
NOISE_FRACTIONS = (0.3,)
#: Every candidate is scored on the held-out samples with ‖u‖ above SCORED_FRACTION · rms‖u‖
#: (the same samples whatever it drops). The methods whose search does this: NOISE_METHODS.
SCORED_FRACTION = 0.3
#: Not pi: on a learnt w̃ in a one-dimensional null space (learn-v, then learn-pi) a small ‖w̃‖ is
#: signal (π nearly along the constraint), not a random direction, and dropping it cost pi's
#: held-out NCPE up to 12× (docs/measurements.md).
NOISE_METHODS = ("lwpi",)


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
            the fixed settings). Grid: K ∈ {n_centres, 16, 25, 49, 100} × σ² factors {1, ½, ¼}
            × cut-offs {cutoff, 1e-9, 1e-12} (relative rule); for lwpi K ∈ {n_centres, 9, 16,
            25, 49, 100} × {1, ¼, 0.1, 0.03, 0.01} × min_norm {min_norm, 0.3 rms‖u‖}
            (:data:`NOISE_FRACTIONS`); the search runs from the smallest basis up
            (:func:`ccl_cli.learn.model_selection.search`).

    Attributes:
        basis_, W_ ((K, q); for lwpi (K, p + 1, q)), n_used_, n_features_in_, tuning_.
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_action_": "value", "n_used_": "value", "W_": "array", "basis_": "basis"}
    #: Fits of the default search at most: pi (5 sizes × 3 widths) × 3 cut-offs × 3 folds = 135;
    #: lwpi (6 sizes × 5 widths) × 2 min_norm × 3 folds = 180.
    TUNE_BUDGET = 400
    method: Method = POLICY_METHOD
    cutoff: NonNegative = 1e-6
    min_norm: NonNegative = 1e-6
    chunk_size: ChunkSize = None
    cutoff_rule: CutoffRule = "relative"

    @property
    def TUNE_CONSERVATIVE(self) -> tuple[str, ...]:  # noqa: N802 - the search's class-level name
        """The cut-off leaves its configured value, lwpi's width the default rule's and ``min_norm``
        (:data:`NOISE_METHODS`) the configured one only for a clear held-out gain
        (:data:`~ccl_cli.learn.model_selection.CONSERVATIVE_GAIN`)."""
        floor = ("min_norm",) if self.method in NOISE_METHODS else ()
        return ("cutoff", WIDTH, *floor) if self.method == "lwpi" else ("cutoff", *floor)

    #: pi-coupled reads the projections in a search's fits (the times it does not read).
    FIT_DATA = ("projections",)

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        if self.method == "lwpi":
            return [((self.n_centres, 9, 16, 25, 49, 100), (1.0, 0.25, 0.1, 0.03, 0.01))]
        return [((self.n_centres, 16, 25, 49, 100), (1.0, 0.5, 0.25))]

    def _tune_grid(self, X: np.ndarray, U: np.ndarray) -> dict[str, list[Any]]:
        """The basis grid (pi on states of ≤ GRID_DIMS dimensions: centres on a grid) and, with the
        relative rule and a method with one global system, the cut-offs {configured, 1e-9, 1e-12}
        (noise-free data want the small ones, noisy data the configured one; candidates differing
        only in the cut-off share their normal equations). lwpi (:data:`NOISE_METHODS`):
        × ``min_norm`` {configured, f · rms‖u‖ for f in :data:`NOISE_FRACTIONS`} (candidates on
        one basis share its features, and a larger ``min_norm`` the sums of the one before)."""
        grid = super()._tune_grid(X, U)
        if grid and self.method in GRID_METHODS and np.shape(X)[1] <= GRID_DIMS:  # centres on a grid
            grid["basis"] = [spec for sizes, widths in self._basis_candidates()
                             for spec in basis_grid(X, sizes, widths, self.seed, centres="grid")]
        if grid and self.cutoff_rule == "relative" and self.method != "lwpi":
            grid["cutoff"] = list(dict.fromkeys([float(self.cutoff), *CUTOFFS]))
        if grid and self.method in NOISE_METHODS:
            floors = [m for m in (f * rms_norm(U) for f in NOISE_FRACTIONS) if m > self.min_norm]
            grid["min_norm"] = [float(self.min_norm), *floors]
        return grid

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            projections: np.ndarray | None = None, t: np.ndarray | None = None) -> PolicyLearner:
        """Fit on states X (N, p), actions U (N, q); ``pi-coupled`` needs ``projections``
        Ñ_n (N, q, q) (true, or from a learnt constraint model). ``groups`` (N,):
        demonstration ids, only for the folds of tuning. The sample times ``t`` every learner
        takes are not read (π̃(x) depends on the state alone)."""
        return self._fit(X, U, groups=groups, projections=projections)

    @property
    def tune_scored_on(self) -> str | None:
        """Which held-out samples score the search's candidates, when not all (the search's
        ``tuning_["scored_on"]``)."""
        if self.method not in NOISE_METHODS:
            return None
        return (f"held-out samples with ‖u‖ > {SCORED_FRACTION:g} · rms‖u‖ (below it the direction of u "
                "is noise), the same for every candidate")

    def _fit_core(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                  basis: Basis | None = None, start: PolicyLearner | None = None,
                  projections: np.ndarray | None = None) -> PolicyLearner:
        """The closed-form fit with a fitted ``basis`` (None: this learner's own); ``start``
        is not needed (nothing iterates)."""
        basis = self._checked_basis(X, U, basis)
        P = self._checked_projections(projections, U)
        rows = np.flatnonzero(self._usable(U))
        if len(rows) < 2:
            raise LearningError(f"fewer than 2 samples with ‖u‖ > {self.min_norm}")
        M, r = self._normal_equations(basis, X, U, P, [None if len(rows) == len(U) else rows])[0]
        return self._finish(basis, M, r, len(rows), U.shape[1])

    def _cv_models(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds, *,
                   basis: Basis | None = None, shared: dict[Any, Any] | None = None,
                   projections: np.ndarray | None = None) -> tuple[PolicyLearner, list[PolicyLearner]]:
        """This candidate on all rows and on each training fold from one pass over the data:
        the normal equations of each test fold (and of the guard gaps of time blocks) are
        summed once, and a fold's training equations are the total minus them (a downdate)
        — the fits the folds would give, for the cost of one fit. The equations and their
        eigen-decompositions are kept in ``shared`` (the search's store) for its other
        candidates on the same basis: other cut-offs cost no pass and no decomposition; the
        features β(X) of the basis too (:meth:`_search_features`): other ``min_norm`` values
        cost no transform."""
        basis = self._checked_basis(X, U, basis)
        P = self._checked_projections(projections, U)
        usable = self._usable(U)
        key = ("policy normal equations", id(basis), self.method, float(self.min_norm))
        shared = {} if shared is None else shared
        if key not in shared:
            B = self._search_features(basis, X, U, shared)
            shared[key] = self._fold_equations(basis, X, U, P, usable, folds, B, shared)
        systems = shared[key]
        q, p = U.shape[1], X.shape[1]
        models = [self._copy(p)._finish(basis, M, r, n, q, eig) for M, r, n, eig in systems]
        return models[0], models[1:]

    def _search_features(self, basis: Basis, X: np.ndarray, U: np.ndarray, shared: dict[Any, Any]
                         ) -> np.ndarray | None:
        """β(X) (N, K) of the search's states on ``basis``, kept in ``shared`` for the candidates
        that follow on the same basis (only the latest basis's, and only when N K floats fit in
        :func:`~ccl_cli.learn.basis.feature_cache_bytes` of X, U; else None: computed per block)."""
        held = shared.get("policy features")
        if held is not None and held[0] is basis:
            return held[1]
        if len(X) * basis.n_features * 8 > feature_cache_bytes(X, U):
            return None
        shared["policy features"] = (basis, basis.transform(X))
        return shared["policy features"][1]

    def _held_out_errors(self, models: list[PolicyLearner], X: np.ndarray, U: np.ndarray, groups: np.ndarray,
                         folds: Folds, *, shared: dict[Any, Any] | None = None,
                         projections: np.ndarray | None = None) -> np.ndarray:
        """−score of each fold's model on its test rows (n_folds,), from the features the search
        keeps (:meth:`_search_features`; else computed per block). For a method of
        :data:`NOISE_METHODS` the test rows with ‖u‖ ≤ :data:`SCORED_FRACTION` · rms‖u‖ (of all
        the search's rows: the same for every candidate, whatever its ``min_norm``) are left
        out: their û is noise."""
        if self.method == "pi-coupled":
            return held_out_errors(models, X, U, groups, folds, projections=projections)
        shared = {} if shared is None else shared
        basis = models[0].basis_
        kept = shared.get("policy held-out")
        if kept is None or kept[0] is not basis:  # the test rows of each fold, with their features
            scored = np.ones(len(U), bool)
            if self.method in NOISE_METHODS:
                scored = np.linalg.norm(U, axis=1) > SCORED_FRACTION * rms_norm(U)
            rows = [test[scored[test]] if scored[test].sum() >= 2 else test for _, test in folds.pairs]
            held = shared.get("policy features")
            B = held[1] if held is not None and held[0] is basis else None
            kept = (basis, [(None if B is None else B[i], X[i], U[i]) for i in rows])
            shared["policy held-out"] = kept
        weighted = self.method == "pi-weighted"
        predicted = [model.predict(Xt) if Bt is None else model._predict_features(Bt, Xt)
                     for model, (Bt, Xt, _) in zip(models, kept[1], strict=True)]
        return np.array([inconsistency_error(P, Ut, weighted=weighted)
                         for P, (_, _, Ut) in zip(predicted, kept[1], strict=True)])

    def _fold_equations(self, basis: Basis, X: np.ndarray, U: np.ndarray, P: np.ndarray | None,
                        usable: np.ndarray, folds: Folds, features: np.ndarray | None = None,
                        shared: dict[Any, Any] | None = None) -> list[tuple]:
        """(M, r, samples used, eigen-decomposition of M) of all rows, then of each training
        fold, from one pass (see :meth:`_cv_models`; ``features``: β(X) (N, K) when known).
        The sums of each test fold, of the rows in none and of each guard gap are kept in
        ``shared`` for the next candidate on this basis: when it uses a subset of these rows (a
        larger ``min_norm``) its sums are these minus those of the rows it drops."""
        n = len(U)
        in_test = np.zeros(n, bool)
        for _, test in folds.pairs:
            in_test[test] = True
        gaps = []
        for train, test in folds.pairs:  # rows neither trained on nor tested (guard gaps)
            out = np.ones(n, bool)
            out[train] = False
            out[test] = False
            gaps.append(out)

        def index_sets(rows: np.ndarray) -> list[np.ndarray]:
            """Of the rows marked in ``rows`` (N,): each test fold's, those in none, each gap's."""
            return [*(test[rows[test]] for _, test in folds.pairs), np.flatnonzero(rows & ~in_test),
                    *(np.flatnonzero(gap & rows) for gap in gaps)]

        key = ("policy sums", id(basis), self.method)
        prior = (shared or {}).get(key)
        if prior is not None and not (usable & ~prior[0]).any():  # fewer rows than the last candidate
            less = self._normal_equations(basis, X, U, P, index_sets(prior[0] & ~usable), features)
            sums = [(M - m, r - v) for (M, r), (m, v) in zip(prior[1], less, strict=True)]
        else:
            sums = self._normal_equations(basis, X, U, P, index_sets(usable), features)
        if shared is not None:
            shared[key] = (usable, sums)
        k = len(folds.pairs)
        M = sum(m for m, _ in sums[: k + 1])
        r = sum(v for _, v in sums[: k + 1])
        systems = [(M, r, int(usable.sum()))]
        for i, (train, _) in enumerate(folds.pairs):
            n_used = int(usable[train].sum())
            if n_used < 2:
                raise LearningError(f"fewer than 2 samples with ‖u‖ > {self.min_norm} in a training fold")
            (Mi, ri), (Mg, rg) = sums[i], sums[k + 1 + i]
            systems.append((M - Mi - Mg, r - ri - rg, n_used))
        return [(M, r, n_used, np.linalg.eigh(M)) for M, r, n_used in systems]

    # -- the parts of a fit ----------------------------------------------------------------
    def _copy(self, n_features: int) -> PolicyLearner:
        """A copy with this learner's parameters, untuned, for a fit of a search on states of
        ``n_features`` dimensions (recorded as ``n_features_in_``, as ``fit`` does)."""
        model = clone(self).set_params(tune=False)
        model.n_features_in_ = int(n_features)
        return model

    def _checked_basis(self, X: np.ndarray, U: np.ndarray, basis: Basis | None) -> Basis:
        """``basis`` or this learner's own fitted on X; lwpi needs an RBF basis."""
        basis = self._fit_basis(X, U) if basis is None else basis
        if self.method == "lwpi" and not isinstance(basis, RBFBasis):
            raise ConfigError("lwpi needs an RBF basis (its centres weight the local models)")
        return basis

    def _checked_projections(self, projections: np.ndarray | None, U: np.ndarray) -> np.ndarray | None:
        """The projections Ñ_n (N, q, q) of pi-coupled (None for the other methods)."""
        if self.method != "pi-coupled":
            return None
        if projections is None:
            raise InputError("pi-coupled needs the projections Ñ_n (true or learnt)")
        P = np.asarray(projections, dtype=float)
        n, q = U.shape
        if P.shape != (n, q, q):
            raise InputError(f"projections must be ({n}, {q}, {q}), got {P.shape}")
        return P

    def _usable(self, U: np.ndarray) -> np.ndarray:
        """Samples that enter the fit (N,): ‖u‖ > ``min_norm`` for pi, pi-weighted and lwpi
        (a direction is needed), all for dpl and pi-coupled."""
        if self.method in ("pi", "pi-weighted", "lwpi"):
            return np.linalg.norm(U, axis=1) > self.min_norm
        return np.ones(len(U), bool)

    def _normal_equations(self, basis: Basis, X: np.ndarray, U: np.ndarray, P: np.ndarray | None,
                          index_sets: list[np.ndarray | None], features: np.ndarray | None = None
                          ) -> list[tuple[np.ndarray, np.ndarray]]:
        """The normal equations (M, r) of each set of rows (an index array, or None: all),
        summed over blocks of ``chunk_size`` rows (``features``: β(X) (N, K) when known, else
        computed per block). Shapes: dpl M (K, K), r (K, q); lwpi
        M (K, D, D), r (K, D) with D = (p + 1) q; else M (K q, K q), r (K q,)."""
        K, q, d = basis.n_features, U.shape[1], X.shape[1] + 1
        out = []
        for idx in index_sets:
            n = len(U) if idx is None else len(idx)

            def take(s: int, e: int, idx: np.ndarray | None = idx) -> tuple[Any, ...]:
                rows = slice(s, e) if idx is None else idx[s:e]
                return (X[rows], U[rows], None if P is None else P[rows],
                        None if features is None else features[rows])

            sums = block_sums(partial(_block, self, basis), take, n, self.chunk_size or CHUNK_ROWS)
            if sums is None:  # no rows: the equations of nothing
                if self.method == "lwpi":
                    sums = np.zeros((K, d * q, d * q)), np.zeros((K, d * q))
                elif self.method == "dpl":
                    sums = np.zeros((K, K)), np.zeros((K, q))
                else:
                    sums = np.zeros((K * q, K * q)), np.zeros(K * q)
            out.append(tuple(sums))
        return out

    def _block_equations(self, B: np.ndarray, X: np.ndarray, U: np.ndarray, P: np.ndarray | None
                         ) -> tuple[np.ndarray, np.ndarray]:
        """The normal equations of one block of samples X (c, p), U (c, q) (P (c, q, q)) with
        features B = β(X) (c, K)."""
        if self.method == "dpl":
            return B.T @ B, B.T @ U
        norm = np.linalg.norm(U, axis=1)
        if self.method in ("pi", "pi-weighted"):
            # rows kron(β_n, û_n) (pi) or kron(β_n, u_n) (pi-weighted), target ‖u‖ or ‖u‖²
            R = kron_rows(B, U / norm[:, None] if self.method == "pi" else U)
            return R.T @ R, R.T @ (norm if self.method == "pi" else norm**2)
        if self.method == "pi-coupled":
            # rows Ñ_n [β_1 I, ..., β_K I] (q, K q): M = Σ_n kron(β_n β_nᵀ, Ñ_nᵀÑ_n),
            # one BLAS product per (i, j) entry; r = Σ_n β_n ⊗ Ñ_nᵀ u_n
            K, q = B.shape[1], U.shape[1]
            G = np.einsum("nai,naj->nij", P, P, optimize=True)
            M = np.empty((K, q, K, q))
            for i in range(q):  # loops over action dimensions, not samples
                for j in range(q):
                    M[:, i, :, j] = (B * G[:, i, j, None]).T @ B
            r = (B.T @ np.einsum("nai,na->ni", P, U, optimize=True)).ravel()
            return M.reshape(K * q, K * q), r
        # lwpi: per centre c, Σ_n β_c(x_n) R_n R_nᵀ with rows R_n = φ_n ⊗ û_n
        phi = np.hstack([X, np.ones((len(B), 1))])
        R = kron_rows(phi, U / norm[:, None])
        D = R.shape[1]
        M = (B.T @ (R[:, :, None] * R[:, None, :]).reshape(len(B), D * D)).reshape(len(B.T), D, D)
        return M, B.T @ (R * norm[:, None])

    def _finish(self, basis: Basis, M: np.ndarray, r: np.ndarray, n_used: int, q: int,
                eig: tuple[np.ndarray, np.ndarray] | None = None) -> PolicyLearner:
        """Solve the normal equations by the eigen pseudo-inverse (``cutoff``, ``cutoff_rule``;
        ``eig``: the eigen-decomposition of M when known) and set the learnt attributes."""
        absolute = self.cutoff_rule == "absolute"
        K = basis.n_features
        vals, vecs = np.linalg.eigh(M) if eig is None else eig
        if self.method == "dpl":
            W = eigen_solve(vals[None], vecs[None], r.T, self.cutoff, absolute).T
        elif self.method == "lwpi":
            W = eigen_solve(vals, vecs, r, self.cutoff, absolute).reshape(K, -1, q)
        else:
            W = eigen_solve(vals, vecs, r, self.cutoff, absolute).reshape(K, q)
        self.basis_, self.W_, self.n_used_, self.n_action_ = basis, W, int(n_used), int(q)
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        """π̃(X): (N, p) → (N, q)."""
        self._check_fitted("W_")
        X = self._check_states(X)
        out = np.empty((len(X), self.n_action_))
        for rows in row_chunks(len(X), self.chunk_size):
            out[rows] = self._predict_features(self.basis_.transform(X[rows]), X[rows])
        return out

    def _predict_features(self, B: np.ndarray, X: np.ndarray) -> np.ndarray:
        """π̃ at states X (c, p) with features B = β(X) (c, K) → (c, q): lwpi Σ_c β_c W_cᵀ φ
        (β rows sum to 1), else Wᵀ β."""
        if self.method != "lwpi":
            return B @ self.W_
        phi = np.hstack([X, np.ones((len(B), 1))])
        local = (B @ self.W_.reshape(len(self.W_), -1)).reshape(len(B), phi.shape[1], -1)
        return np.einsum("ni,niq->nq", phi, local)

    def score(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
              projections: np.ndarray | None = None, t: np.ndarray | None = None) -> float:
        """Minus the normalised inconsistency error (§5) of π̃ on actions U (N, q) at states
        X (N, p): −mean ‖u − ûûᵀπ̃(x)‖² / Σ var(u) (pi-weighted: terms weighted by ‖u‖²);
        pi-coupled with ``projections`` Ñ (N, q, q): −mean ‖u − Ñπ̃(x)‖² / Σ var(u). Higher is better."""
        P = self.predict(X)
        U = np.asarray(U, dtype=float)
        if self.method == "pi-coupled":
            return -inconsistency_error(P, U, projections)
        return -inconsistency_error(P, U, weighted=self.method == "pi-weighted")


    def check_shapes(self) -> None:
        """W_ (K, q), or (K, p + 1, q) for lwpi, with the basis's K and p."""
        K = self._basis_width()
        want = (K, self.basis_.n_state + 1, self.n_action_) if self.method == "lwpi" else (K, self.n_action_)
        if self.W_ is None or self.W_.shape != want:
            raise self._shape_error("W_")
        super().check_shapes()


def rms_norm(U: np.ndarray) -> float:
    """The root mean square of the action norms, sqrt(mean_n ‖u_n‖²), of U (N, q)."""
    return float(np.sqrt(np.mean(np.sum(np.square(U), axis=1))))


def _block(learner: PolicyLearner, basis: Basis, X: np.ndarray, U: np.ndarray, P: np.ndarray | None,
           features: np.ndarray | None) -> tuple[np.ndarray, np.ndarray]:
    """The normal equations of one block of rows (:meth:`PolicyLearner._block_equations`), its
    features β(X) computed here when not given: a function of its arguments alone, so a cluster's
    worker can compute it (:mod:`ccl_cli.learn.blocksums`)."""
    B = basis.transform(X) if features is None else features
    return learner._block_equations(B, X, U, P)
