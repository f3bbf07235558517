"""Learning the null-space component w ("ncl", ALGORITHMS.md §4).

Model w̃(x) = W β(x), W ∈ R^{q×K}. Since N u = w and v ⟂ w, a consistent model equals
the projection of u onto itself: minimise E[w̃] = Σ_n ‖P̃_n u_n − w̃_n‖², with
P̃_n = w̃_n w̃_nᵀ / ‖w̃_n‖². With a = u_nᵀ w̃_n and c = ‖w̃_n‖², the residual norm is
|a − c| / √c; the original minimises the scalar residual r_n = (a − c + 1e-8) / √c by
Levenberg–Marquardt from ordinary least squares of U on β (eigen-decomposition
pseudo-inverse, eigenvalues below 1e-8 of the largest dropped).

That residual has a wall: r_n = u_nᵀŵ_n − ‖w̃_n‖ jumps with the direction ŵ_n where w̃_n
crosses 0, and its gradient grows as 1/√c there. On 1e4 samples a single sample next to
the zero set of w̃ held 99 % of JᵀJ, and Levenberg–Marquardt crawled: hundreds of passes,
and at N = 1e5 it had not converged after 1000 (25 s). So the fit runs in four stages:

1. the smooth residual r'_n = a − c (same zero set, no wall; ∂r'/∂w̃ = u − 2w̃) from the
   OLS start, to the loose tolerance :data:`STAGE_TOL`;
2. the *smoothed* original residual

       r_n = (a − c + 1e-8) / √(c + δ²),   δ² = ``smoothing`` · mean_n ‖w̃_n‖²

   with w̃ the stage-1 solution (default 1e-4: δ is 1 % of the RMS of w̃), to
   STAGE_TOL/100. Samples with ‖w̃_n‖ ≫ δ keep the original residual; the few near
   w̃ = 0 are smoothly down-weighted instead of dominating. Jacobian
   ∂r_n/∂W = [(u − 2w̃)/√(c+δ²) − r w̃/(c+δ²)] β_nᵀ;
3. the same residual on all rows from that start with almost no damping (μ₀ = 1e-12:
   the start is near the optimum; with μ₀ = 1e-3 the damped steps needed ~20 passes to
   open up along the flat directions that matter for the test error, μ₀ = 1e-12 took 7),
   to ``tol``;
4. the original residual (δ = 0) for at most :data:`ORIGINAL_PASSES` passes
   (:data:`ORIGINAL_FULL_PASSES` over all rows after a subsample), from the stage-3
   optimum: near it the wall samples are few and placed, so these passes lower the
   original cost to, or below, where 1000 passes from the smooth start ended.

Stages 1 and 2 run on a seeded subsample of :func:`subsample_size` rows when N is larger
(otherwise on all rows, and stage 3 is their continuation); stage 3 then takes at most
:data:`FULL_PASSES` passes over all rows (so a fit costs a bounded number of passes over the
data, O(N)). A fit started from another fit (a search's winner on a subset of the rows) runs
its stage 2 on that subsample too before the passes over all rows. ``smoothing=0`` minimises
the original residual itself in stages 2–3 (the original's optimum, slowly: ~180 passes
on 500 samples); ``polish=False`` stops after stage 1 (then run on all rows). Times and
errors before → after the staging: docs/measurements.md ("ncl").

Scale: the Jacobian row of sample n is vec(g_n β_nᵀ) with g_n ∈ R^q the bracket above, so
each Levenberg–Marquardt iteration is one pass over the data in row blocks that sums
JᵀJ = Σ kron(g gᵀ, β βᵀ) and Jᵀr (:func:`~ccl_cli.learn.linalg.kron_least_squares`): the
cost is O(N (Kq)²) flops per accepted step (a rejected one costs a residual pass,
O(N K q)) and memory O(chunk · Kq + (Kq)²), never N × Kq.
"""

from __future__ import annotations

import contextvars
from collections.abc import Callable
from typing import Any, ClassVar

import numpy as np

from ccl_cli.errors import LearningError
from ccl_cli.learn import blocksums
from ccl_cli.learn.base import Estimator
from ccl_cli.learn.basis import Basis, BasisParams, Blocks, feature_blocks, feature_cache_bytes
from ccl_cli.learn.consistency import npe_error
from ccl_cli.learn.linalg import (
    CHUNK_ROWS,
    WARM_TOL,
    eigen_lstsq,
    kron_least_squares,
    kron_normal,
    lift_to_rows,
    row_chunks,
)
from ccl_cli.learn.model_selection import Tunable
from ccl_cli.learn.params import ChunkSize, MaxIter, NonNegative, SeedParams, Tolerance, parameters

#: ``residual(W, rows, β)`` → (r (c,), ∂r/∂w̃ (c, q)), the callback of kron_least_squares.
Residual = Callable[[np.ndarray, slice, np.ndarray], tuple[np.ndarray, np.ndarray]]

EPS_RESIDUAL = 1e-8
#: δ² of the smoothed residual, relative to the mean ‖w̃_n‖² of the stage-1 solution.
SMOOTHING = 1e-4
#: Relative tolerance of the stages before the last (the last uses ``tol``).
STAGE_TOL = 1e-4
#: Rows of the subsample the first stages run on (at least 20 per parameter).
SUBSAMPLE_ROWS = 10_000
#: Passes of the last stage (the original residual, from the smoothed optimum).
ORIGINAL_PASSES = 5
#: Passes over all rows of stages 3 and 4 when a subsample ran first (its optimum is near): the
#: fit's passes over all N are bounded by a count, FULL_PASSES + ORIGINAL_FULL_PASSES + 2,
#: whatever N (issue 31: 10 + 5 took 16 s of CPU at N = 7·10⁵ with 36 centres, 4 + 2 7 s; the
#: held-out NPE 0.6–1.8 % higher on the 10⁵–10⁶ tracker and varying toy samples, where the
#: search's choice of the basis moves it by 20 %; docs/measurements.md, "ncl").
FULL_PASSES = 4
ORIGINAL_FULL_PASSES = 2


def subsample_size(n: int, n_params: int) -> int:
    """Rows of the stage-1/2 subsample: max(10 000, 20 · K q), or all n when not larger."""
    return min(n, max(SUBSAMPLE_ROWS, 20 * n_params))


def smooth_residual(U: np.ndarray) -> Residual:
    """r'_n = u_nᵀw̃_n − ‖w̃_n‖², ∂r'/∂w̃ = u − 2w̃ (stage 1)."""

    def residual(W: np.ndarray, rows: slice, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Ub = U[rows]
        Wt = B @ W.T  # (c, q)
        return np.einsum("nq,nq->n", Ub - Wt, Wt), Ub - 2.0 * Wt

    residual.made_by = (smooth_residual, ())  # type: ignore[attr-defined] - rebuilt per block on a cluster
    return residual


def wall_residual(U: np.ndarray, delta2: float) -> Residual:
    """r_n = (a − c + 1e-8)/√(c + δ²) and its w̃-gradient (stage 2; δ² = 0: the original)."""

    def residual(W: np.ndarray, rows: slice, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Ub = U[rows]
        Wt = B @ W.T  # (c, q)
        a = np.einsum("nq,nq->n", Ub, Wt)
        c = np.einsum("nq,nq->n", Wt, Wt)
        d = np.maximum(c + delta2, 1e-300)
        sd = np.sqrt(d)
        r = (a - c + EPS_RESIDUAL) / sd
        return r, (Ub - 2.0 * Wt) / sd[:, None] - (r / d)[:, None] * Wt

    residual.made_by = (wall_residual, (delta2,))  # type: ignore[attr-defined]
    return residual


#: The rows of the fit running now held by a cluster's workers, (n, U and X blocks, their features).
_HELD: contextvars.ContextVar[tuple[int, Any, Any] | None] = contextvars.ContextVar("ccl_ncl_held",
                                                                                       default=None)


def _features(basis: Basis, U: np.ndarray, X: np.ndarray) -> tuple[np.ndarray]:
    """β(X) of one block (on the worker that holds it)."""
    return (basis.transform(X),)


def _pass_block(made_by: tuple[Callable, tuple], W: np.ndarray, full: bool, U: np.ndarray, X: np.ndarray,
                B: np.ndarray) -> tuple[np.ndarray, ...]:
    """One block's part of a Levenberg–Marquardt pass (:func:`~ccl_cli.learn.linalg.kron_least_squares`):
    (Σ r²,) and, for a full pass, JᵀJ and Jᵀr of its rows — the residual rebuilt from its maker."""
    factory, args = made_by
    with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
        r, G = factory(U, *args)(W, slice(None), B)
        cost = np.array([float(r @ r)])
        if not full:
            return (cost,)
        M, g = kron_normal(G, B, r)
    return cost, M, g


@parameters
class NullSpaceComponent(Tunable, Estimator, BasisParams, SeedParams):
    """Learns w̃(x) = W β(x) from observations u = v + w (the stages: module docstring).

    Args:
        basis, n_centres, seed: feature map (normalised RBF by default); ``seed`` also
            draws the subsample of the first stages.
        max_iter: passes over the data of each stage at most (original: 1000).
        tol: tolerance of stages 3 and 4: each stops when an accepted step lowers the cost
            by less than ``tol`` relatively, the Gauss–Newton model predicts a decrease
            below ``tol`` times the cost, the step is below ``tol`` relative to W, or the
            scaled gradient is below ``tol`` (:func:`~ccl_cli.learn.linalg.kron_least_squares`;
            original: 1e-9); stages 1–2 use :data:`STAGE_TOL` and STAGE_TOL/100.
        chunk_size: rows per block of the passes over the data (default 8192).
        polish: run stages 2–4 (default). ``False`` stops after stage 1 (the smooth
            residual; docs/measurements.md).
        smoothing: δ² of stages 2–3 relative to mean ‖w̃‖² (0: the original residual
            throughout, and no stage 4).
        tune: choose the basis by cross-validation (:class:`ccl_cli.learn.model_selection.Tuned`;
            True by default, a dict ``{budget, grid, folds, max_rows}`` to adjust, False for
            the fixed settings). Grid: K ∈ {n_centres, 16, 36, 64, 100} k-means RBF centres
            (at most N/2; default width rule), run from the smallest up while a larger one
            helps (:func:`ccl_cli.learn.model_selection.search`), scored by held-out NPE over
            :attr:`TUNE_FOLDS` folds on at most :attr:`TUNE_MAX_ROWS` rows. A basis the user
            fixed (linear, explicit centres or σ²) is not tuned.

    Attributes:
        basis_, W_ (q, K), cost_ (Σ r² of the original residual at W_), objective_ (the
        minimised Σ r² of the last stage), n_iter_ (passes over the data of all stages,
        full or residual-only, on the subsample or on all rows), stop_reason_ (why the
        last stage stopped: "cost", "predicted", "step", "gradient", "max_iter",
        "non-finite", "budget" when stage 4 used its ORIGINAL_PASSES, or "zero start" when
        the least-squares start is W = 0 — BᵀU = 0, e.g. u ≡ 0 — and is kept), stages_ (per
        stage: stage name, rows, delta2, full_passes, cost_passes, accepted, stop).
    """

    #: Folds of the basis search: 5, not 3 (docs/measurements.md, "ncl").
    TUNE_FOLDS = 5
    #: Rows of the basis search at most (a seeded subset above; docs/measurements.md, "Tuning":
    #: the same test errors at N = 1e5 as with 20000 rows, at a third of the time).
    TUNE_MAX_ROWS = 5000
    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_action_": "value", "cost_": "value", "n_iter_": "value",
        "stop_reason_": "value", "W_": "array", "basis_": "basis"}
    max_iter: MaxIter = 1000
    tol: Tolerance = 1e-9
    chunk_size: ChunkSize = None
    polish: bool = True
    smoothing: NonNegative = SMOOTHING

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        return [((self.n_centres, 16, 36, 64, 100), (1.0,))]

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None) -> NullSpaceComponent:
        """Learn w̃ from states X (N, p) and actions U (N, q); ``groups`` (N,):
        demonstration ids, for the folds of tuning. The sample times ``t`` every learner takes
        are not read (w̃(x) depends on the state alone)."""
        return self._fit(X, U, groups=groups)

    def _fit_core(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                  basis: Basis | None = None, start: NullSpaceComponent | None = None
                  ) -> NullSpaceComponent:
        """The staged fit with a fitted ``basis`` (None: this learner's own). From ``start``
        (a fitted model on the same basis, e.g. on other rows of the same data) the first
        stages are skipped: its W (seen through these rows when it was fitted on more,
        :func:`~ccl_cli.learn.linalg.lift_to_rows`) is the start of stage 3 (δ² from its w̃ on
        these rows; with
        ``polish=False`` of the smooth stage on all rows), run to
        :data:`~ccl_cli.learn.linalg.WARM_TOL`."""
        self.basis_ = self._fit_basis(X, U) if basis is None else basis
        chunk = self.chunk_size or CHUNK_ROWS
        if _HELD.get() is None and blocksums.worth_sending(len(U), chunk):  # its workers hold the rows
            rows = blocksums.Held.send(lambda s, e: (U[s:e], X[s:e]), len(U), chunk)
            token = _HELD.set((len(U), rows, rows.map(_features, self.basis_)))
            try:
                return self._fit_core(X, U, groups=groups, basis=self.basis_, start=start)
            finally:
                _HELD.reset(token)
        cache = feature_cache_bytes(X, U)
        blocks = feature_blocks(self.basis_, X, self.chunk_size, cache)
        n, q = U.shape
        K = self.basis_.n_features
        m = subsample_size(n, K * q)
        if m < n:
            keep = np.sort(np.random.default_rng(self.seed).choice(n, m, replace=False))
            U_s, sub_blocks = U[keep], feature_blocks(self.basis_, X[keep], self.chunk_size, cache)
        else:
            U_s, sub_blocks = U, blocks
        self.stages_: list[dict] = []
        if start is not None:  # the last stages from a fit of the same basis on other rows of the data
            W = np.array(start.W_, dtype=float)
            if start._fit_rows > n:  # a fit on more rows (a fold's start): what these rows see of it
                W = lift_to_rows(W, blocks)
            if self.polish:  # on a subsample first when there are more rows: fewer passes over all of them
                return self._polish(W, blocks, U, n, m, sub_blocks, U_s, WARM_TOL)
            W, cost = self._stage("smooth", W, blocks, smooth_residual(U), n, max(self.tol, WARM_TOL), 1e-12)
            return self._done(W, cost, blocks, U, n, q)
        BtB, BtU = np.zeros((K, K)), np.zeros((K, q))
        for rows, B in blocks():
            BtB += B.T @ B
            BtU += B.T @ U[rows]
        W = eigen_lstsq(BtB, BtU.T, 1e-8)  # (q, K): the OLS start
        if not np.any(W):  # BᵀU = 0: no action has a component along the features
            return self._finish(W, 0.0, 0.0, "zero start", q)
        last = not self.polish and m == n
        W, cost = self._stage("smooth", W, sub_blocks if m < n else blocks, smooth_residual(U_s), m,
                              self.tol if last else STAGE_TOL, 1e-3)
        if not self.polish:
            if m < n:
                W, cost = self._stage("smooth", W, blocks, smooth_residual(U), n, self.tol, 1e-12)
            return self._done(W, cost, blocks, U, n, q)
        return self._polish(W, blocks, U, n, m, sub_blocks, U_s)

    def _mean_square(self, W: np.ndarray, blocks: Blocks, n: int) -> float:
        """mean_n ‖w̃_n‖² over the rows of ``blocks`` (n of them)."""
        total = 0.0
        with np.errstate(over="ignore", invalid="ignore"):
            for _, B in blocks():
                total += float(np.sum((B @ W.T) ** 2))
        return total / n

    def _polish(self, W: np.ndarray, blocks: Blocks, U: np.ndarray, n: int, m: int, sub_blocks: Blocks,
                U_s: np.ndarray, tol: float | None = None) -> NullSpaceComponent:
        """Stages 2–4 from W (q, K): the smoothed original residual on the m-row subsample
        (when m < n) and on all n rows, then at most ORIGINAL_PASSES of the original; stages
        3–4 to ``tol`` when larger than the learner's."""
        tol = max(self.tol, tol or 0.0)
        delta2 = self.smoothing * self._mean_square(W, sub_blocks, m)
        name = "smoothed original" if delta2 > 0 else "original"
        if m < n:
            W, cost = self._stage(name, W, sub_blocks, wall_residual(U_s, delta2), m, STAGE_TOL * 1e-2,
                                  1e-8, delta2)
        W, cost = self._stage(name, W, blocks, wall_residual(U, delta2), n, tol,
                              1e-12 if m < n or not self.stages_ else 1e-8, delta2,
                              min(FULL_PASSES, self.max_iter) if m < n else None)
        if m < n and self.stages_[-1]["stop"] == "max_iter":
            self.stages_[-1]["stop"] = "budget"
        if delta2 > 0:
            W, cost = self._stage("original", W, blocks, wall_residual(U, 0.0), n, tol, 1e-12, 0.0,
                                  min(ORIGINAL_FULL_PASSES if m < n else ORIGINAL_PASSES, self.max_iter))
            if self.stages_[-1]["stop"] == "max_iter":
                self.stages_[-1]["stop"] = "budget"
        return self._done(W, cost, blocks, U, n, U.shape[1])

    def _stage(self, name: str, W: np.ndarray, blocks: Blocks, residual: Residual, rows: int, tol: float,
               mu0: float, delta2: float | None = None, passes: int | None = None
               ) -> tuple[np.ndarray, float]:
        """One Levenberg–Marquardt stage; its passes and stop reason go to ``stages_``."""
        info: dict = {}
        held = _HELD.get()
        on_cluster = None
        if held is not None and held[0] == rows and hasattr(residual, "made_by"):  # all rows: on the cluster
            def on_cluster(W: np.ndarray, full: bool) -> tuple[float, np.ndarray | None, np.ndarray | None]:
                sums = held[1].sums(_pass_block, residual.made_by, W, full, beside=(held[2],))
                return float(sums[0][0]), *(sums[1:] if full else (None, None))
        with np.errstate(over="ignore", invalid="ignore", divide="ignore"):  # checked by _done
            W, cost, _ = kron_least_squares(W, blocks, residual, passes or self.max_iter, tol, info=info,
                                            mu0=mu0, passes=on_cluster)
        self.stages_.append({"stage": name, "rows": rows, "delta2": delta2, **info})
        return W, cost

    def _done(self, W: np.ndarray, cost: float, blocks: Blocks, U: np.ndarray, n: int, q: int
              ) -> NullSpaceComponent:
        """The original cost at W (a pass, unless the last stage minimised it on all rows)."""
        if self.stages_[-1]["delta2"] == 0.0 and self.stages_[-1]["rows"] == n:
            original_cost = cost  # the last stage minimised the original residual itself
        else:
            original, original_cost = wall_residual(U, 0.0), 0.0
            with np.errstate(over="ignore", invalid="ignore", divide="ignore"):
                for rows, B in blocks():
                    r = original(W, rows, B)[0]
                    original_cost += float(r @ r)
        if not np.isfinite(original_cost):
            bad = next((s["stage"] for s in self.stages_ if s["stop"] == "non-finite"), "original")
            raise LearningError(f"ncl: the cost is not finite in stage {bad!r} "
                                f"(actions of magnitude {np.abs(U).max():.3g} overflow its squares)")
        return self._finish(W, cost, original_cost, self.stages_[-1]["stop"], q)

    def _finish(self, W: np.ndarray, objective: float, cost: float, stop: str, q: int
                ) -> NullSpaceComponent:
        self.W_, self.objective_, self.cost_, self.stop_reason_ = W, objective, cost, stop
        self.n_iter_ = sum(s["full_passes"] + s["cost_passes"] for s in self.stages_)
        self.n_action_ = q
        return self

    def predict(self, X: np.ndarray) -> np.ndarray:
        """w̃(X) = W β(X): (N, p) → (N, q), in row blocks."""
        self._check_fitted("W_")
        X = self._check_states(X)
        out = np.empty((len(X), self.W_.shape[0]))
        for rows in row_chunks(len(X), self.chunk_size):
            out[rows] = self.basis_.transform(X[rows]) @ self.W_.T
        return out

    def task_component(self, X: np.ndarray, U: np.ndarray) -> np.ndarray:
        """ṽ = u − w̃(x): (N, q)."""
        return np.asarray(U, dtype=float) - self.predict(X)

    def score(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
              t: np.ndarray | None = None) -> float:
        """−NPE of actions U (N, q) at states X (N, p) (§6): −mean ‖P̃u − w̃‖² / Σ var(u),
        P̃ = w̃w̃ᵀ/‖w̃‖²; higher is better."""
        return -npe_error(self.predict(X), np.asarray(U, dtype=float))

    def check_shapes(self) -> None:
        """W_ (q, K), K the basis's features."""
        K = self._basis_width()
        if self.W_ is None or self.W_.shape != (self.n_action_, K):
            raise self._shape_error("W_")
        super().check_shapes()
