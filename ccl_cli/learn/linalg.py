"""Batched linear algebra shared by the learners (stacks are the leading axis)."""

from __future__ import annotations

from collections.abc import Callable, Iterable

import numpy as np

#: Relative singular-value cut-off of the pseudo-inverse (ALGORITHMS.md §1).
PINV_RTOL = 1e-10


def row_space_projection(A: np.ndarray, rtol: float = PINV_RTOL) -> np.ndarray:
    """``A⁺A`` for a stack of matrices.

    Args:
        A: (..., s, q).
        rtol: singular values below ``rtol * max(σ)`` (per matrix) are dropped.

    Returns:
        (..., q, q) orthogonal projection onto the row space of each ``A``.
    """
    A = np.asarray(A, dtype=float)
    _, sv, vh = np.linalg.svd(A, full_matrices=False)
    keep = sv > rtol * np.maximum(sv[..., :1], np.finfo(float).tiny)
    vk = vh * keep[..., :, None]
    return np.einsum("...ki,...kj->...ij", vk, vk)


def nullspace_projection(A: np.ndarray, rtol: float = PINV_RTOL) -> np.ndarray:
    """``N = I − A⁺A`` (ALGORITHMS.md §1) for a stack of matrices (..., s, q) → (..., q, q)."""
    q = np.shape(A)[-1]
    return np.eye(q) - row_space_projection(A, rtol)


def unit_rows(V: np.ndarray, eps: float = 1e-300) -> np.ndarray:
    """Rows of ``V`` scaled to unit length (zero rows stay zero)."""
    norm = np.linalg.norm(V, axis=-1, keepdims=True)
    return V / np.maximum(norm, eps)


def total_variance(Y: np.ndarray, ddof: int = 1) -> float:
    """Sum over dimensions of the per-dimension sample variance of ``Y`` (N, d)."""
    Y = np.asarray(Y, dtype=float)
    if Y.ndim == 1:
        Y = Y[:, None]
    if Y.shape[0] <= ddof:
        return float("nan")
    centred = Y - Y.mean(0)  # one pass for the sum of squares (np.var's axis-0 reductions: 1.6×)
    return float(np.einsum("ij,ij->", centred, centred)) / (Y.shape[0] - ddof)


def generalized_eigh(A: np.ndarray, B: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The symmetric-definite problem A w = λ B w (A symmetric, B symmetric positive definite,
    (d, d)): eigenvalues (d,) ascending and eigenvectors W (d, d) as columns with Wᵀ B W = I — as
    LAPACK's sygv: B = L Lᵀ (Cholesky), the standard problem of L⁻¹ A L⁻ᵀ, W = L⁻ᵀ V. NumPy only
    (SciPy's linalg costs a run 35 MiB of memory and 0.2 s to import)."""
    L = np.linalg.cholesky(B)
    C = np.linalg.solve(L, np.linalg.solve(L, A).T)  # L⁻¹ A L⁻ᵀ (A symmetric)
    lam, V = np.linalg.eigh((C + C.T) / 2)
    return lam, np.linalg.solve(L.T, V)


def eigen_lstsq(M: np.ndarray, r: np.ndarray, cutoff: float, absolute: bool = False) -> np.ndarray:
    """Solve the symmetric normal equations ``M w = r`` by eigen-decomposition.

    Eigenvalues of ``M`` below ``cutoff · max(eig)`` (or below ``cutoff`` itself with
    ``absolute``, the original library's rule) are discarded (a regularised
    pseudo-inverse, ALGORITHMS.md §4–§5). ``M`` is (..., d, d), ``r`` (..., d).
    """
    vals, vecs = np.linalg.eigh(M)
    return eigen_solve(vals, vecs, r, cutoff, absolute)


def eigen_solve(vals: np.ndarray, vecs: np.ndarray, r: np.ndarray, cutoff: float,
                absolute: bool = False) -> np.ndarray:
    """:func:`eigen_lstsq` from the eigen-decomposition (vals (..., d), vecs (..., d, d)) of M,
    so several cut-offs of one M cost one decomposition."""
    top = np.maximum(vals[..., -1:], np.finfo(float).tiny)
    threshold = cutoff if absolute else cutoff * top
    inv = np.where(vals > threshold, 1.0 / np.where(vals > 0, vals, 1.0), 0.0)
    coef = np.einsum("...ij,...i->...j", vecs, r) * inv
    return np.einsum("...ij,...j->...i", vecs, coef)


# -- chunked normal equations (issue 10: memory independent of N) --------------------------

#: Relative eigenvalue cut-off of the damped normal matrix in the LM steps: directions
#: of JᵀJ weaker than this (near-collinear RBF features) are not stepped along.
LM_CUTOFF = 1e-12

#: Relative tolerance of an iterative fit started from a fit of the same model and basis on
#: other rows of the same data (the fold fits of a search, the winner's fit on all rows after
#: a search on a subset): it starts next to its optimum, and below this the passes only
#: crawl along directions the data barely determine (docs/measurements.md, "Tuning").
WARM_TOL = 1e-6

#: Rows per block of the chunked passes: temporaries are O(CHUNK_ROWS · K q), not O(N · K q).
CHUNK_ROWS = 8192


def row_chunks(n: int, size: int | None = None) -> list[slice]:
    """Consecutive slices of at most ``size`` (default :data:`CHUNK_ROWS`) rows covering 0..n."""
    size = int(size or CHUNK_ROWS)
    if size < 1:
        raise ValueError(f"chunk size must be positive, got {size}")
    return [slice(i, min(i + size, n)) for i in range(0, n, size)]


def lift_to_rows(W: np.ndarray, blocks: Callable[[], Iterable[tuple[slice, np.ndarray]]],
                 rel: float = 1e-6) -> np.ndarray:
    """A map y = W β (W (m, K)) seen only through the rows of ``blocks`` ((rows, β) pairs): the
    ridge regression of its values at those rows on their features, argmin_V Σ ‖V β_n − W β_n‖²
    + λ‖V‖², λ = ``rel`` · tr(BᵀB)/K, summed block by block → V (m, K). Where the rows pin the
    features down V = W; along a direction they leave free (features of a region no row
    visits) V has the ridge's small weights, as a fit from scratch would. The start of a fit
    taken from a fit on more rows (a fold's, from the fit of all of them) so carries nothing
    the other rows alone taught it: no held-out information leaks into the fold."""
    K = W.shape[1]
    G, R = np.zeros((K, K)), np.zeros((K, W.shape[0]))
    for _, B in blocks():
        G += B.T @ B
        R += B.T @ (B @ W.T)
    lam = rel * np.trace(G) / K
    return np.linalg.solve(G + lam * np.eye(K), R).T


def kron_rows(G: np.ndarray, B: np.ndarray) -> np.ndarray:
    """Rows vec(g_n β_nᵀ) of a Jacobian whose parameters are W (m, K) flattened row-major:
    G (c, m), B (c, K) → (c, m K)."""
    return (G[:, :, None] * B[:, None, :]).reshape(len(B), -1)


def kron_normal(G: np.ndarray, B: np.ndarray, r: np.ndarray | None = None
                ) -> tuple[np.ndarray, np.ndarray | None]:
    """One block of the normal equations of rows J_n = vec(g_n β_nᵀ):

        JᵀJ = Σ_n kron(g_n g_nᵀ, β_n β_nᵀ) (m K, m K),   Jᵀr = vec(Σ_n r_n g_n β_nᵀ) (m K,),

    for G (c, m), B (c, K), r (c,) or None — one BLAS product on a (c, m K) block.
    """
    J = kron_rows(G, B)
    return J.T @ J, (None if r is None else ((G * r[:, None]).T @ B).ravel())


def kron_least_squares(
    W0: np.ndarray,
    blocks: Callable[[], Iterable[tuple[slice, np.ndarray]]],
    residual: Callable[[np.ndarray, slice, np.ndarray], tuple[np.ndarray, np.ndarray]],
    max_iter: int = 1000,
    tol: float = 1e-9,
    cutoff: float = LM_CUTOFF,
    info: dict | None = None,
    mu0: float = 1e-3,
    passes: Callable[[np.ndarray, bool], tuple[float, np.ndarray | None, np.ndarray | None]] | None = None,
) -> tuple[np.ndarray, float, int]:
    """Levenberg–Marquardt on accumulated normal equations for min_W Σ_n r_n(W)².

    The model is r_n = r(W β_n, data_n) with W (m, K), so the Jacobian row of sample n is
    vec(g_n β_nᵀ), g_n = ∂r_n/∂(W β_n) (m,). ``residual(W, rows, β)`` returns
    (r (c,), g (c, m)); ``blocks()`` yields (rows slice, features β (c, K)). No N × m K
    matrix is ever formed; there are two kinds of chunked pass over the data:

    * a *full* pass sums JᵀJ (m K × m K, :func:`kron_normal`), Jᵀr and Σ r² block by block
      — O(N (mK)²) flops;
    * a *cost* pass sums only Σ r² — O(N m K) flops, 4–20× cheaper.

    Steps solve (JᵀJ + μ D) δ = −Jᵀr with D the running maximum of diag(JᵀJ)
    (Marquardt/MINPACK scaling) and μ updated from the gain ratio (Nielsen). The scaled
    matrix D^{-1/2} JᵀJ D^{-1/2} is eigen-decomposed once per accepted point, so a rejected
    step costs one cost pass and no new factorisation; directions whose damped eigenvalue
    is below ``cutoff`` times the largest are not stepped along (near-collinear RBF
    features, along which the weights would otherwise grow without improving the fit).
    A trial after an accepted step is evaluated by a full pass (it is usually accepted
    too); after a rejection, trials are cost passes and the accepted point then gets its
    full pass. Stops when an accepted step lowers the cost by less than ``tol``
    relatively ("cost"); when the undamped Gauss–Newton step predicts a decrease below
    ``tol`` times the cost ("predicted": the Newton decrement (Jᵀr)ᵀ(JᵀJ)⁻¹Jᵀr with the
    eigenvalues floored at the cut-off; this saves the pass that would only confirm
    convergence); when the step is below ``tol`` relative to W ("step") or the scaled
    gradient below ``tol`` ("gradient"); or after ``max_iter`` passes of either kind
    ("max_iter"). A non-finite cost or normal matrix at the start stops at once, and one
    at an accepted trial leaves W at the last finite point ("non-finite").

    ``mu0`` is the starting damping (relative to the scaled diagonal): 1e-3 from a rough
    start; near-zero from a start close to the optimum, where the damped steps would
    otherwise need many passes to open up along flat directions.

    Args:
        info: if given, receives ``stop`` (the reason above), ``full_passes``,
            ``cost_passes`` and ``accepted`` (steps).
        passes: if given, ``passes(W, full)`` computes a pass instead of ``blocks`` and
            ``residual`` here: (Σ r², JᵀJ, Jᵀr) for a full pass, (Σ r², None, None) for a cost
            pass (e.g. on a cluster's workers, :mod:`ccl_cli.learn.blocksums`).

    Returns:
        (W (m, K), cost Σ r², passes over the data of either kind).
    """
    shape = np.shape(W0)

    def passes_here(W: np.ndarray, with_normal: bool) -> tuple[float, np.ndarray | None, np.ndarray | None]:
        """A pass over ``blocks`` in this process: Σ r², and JᵀJ, Jᵀr with ``with_normal``."""
        cost, H, Jtr = 0.0, None, None
        if with_normal:
            H, Jtr = np.zeros((W.size, W.size)), np.zeros(W.size)
        for rows, B in blocks():
            r, G = residual(W, rows, B)
            if with_normal:
                M, g = kron_normal(G, B, r)
                H += M
                Jtr += g
            cost += float(r @ r)
        return cost, H, Jtr

    run_pass = passes_here if passes is None else passes

    def full(w: np.ndarray) -> tuple[float, np.ndarray, np.ndarray]:
        return run_pass(w.reshape(shape), True)  # type: ignore[return-value]

    def cost_only(w: np.ndarray) -> float:
        return run_pass(w.reshape(shape), False)[0]

    counts = {"full_passes": 1, "cost_passes": 0, "accepted": 0}

    def done(reason: str, w: np.ndarray, cost: float) -> tuple[np.ndarray, float, int]:
        if info is not None:
            info.update(counts, stop=reason)
        return w.reshape(shape), cost, counts["full_passes"] + counts["cost_passes"]

    w = np.asarray(W0, dtype=float).ravel().copy()
    cost, H, Jtr = full(w)
    if not (np.isfinite(cost) and np.isfinite(H).all() and np.isfinite(Jtr).all()):
        return done("non-finite", w, cost)
    D = np.diag(H)
    diag = np.maximum(D, 1e-12 * max(float(np.max(D)), 1e-300))
    mu, nu = mu0, 2.0
    optimistic = True  # evaluate the next trial with a full pass
    new_H = new_Jtr = None
    while True:
        scaled = np.abs(Jtr) / np.sqrt(diag * max(cost, 1e-300))
        if np.max(scaled, initial=0.0) <= tol:
            return done("gradient", w, cost)
        s = 1.0 / np.sqrt(diag)
        vals, vecs = np.linalg.eigh(H * s[:, None] * s[None, :])
        proj = vecs.T @ (Jtr * s)
        # Newton decrement of the Gauss–Newton model: Jᵀr (JᵀJ)⁻¹ Jᵀr is the cost decrease
        # its undamped step predicts (eigenvalues floored at the cut-off, so weak directions
        # count at their largest); below tol · cost no step is worth a pass.
        floor = cutoff * max(float(vals[-1]), np.finfo(float).tiny)
        if float(np.sum(proj**2 / np.maximum(vals, floor))) <= tol * cost:
            return done("predicted", w, cost)
        while True:
            if counts["full_passes"] + counts["cost_passes"] >= max_iter:
                return done("max_iter", w, cost)
            damped = vals + mu
            keep = damped > cutoff * max(float(damped[-1]), np.finfo(float).tiny)
            step = -s * (vecs @ np.where(keep, proj / np.where(keep, damped, 1.0), 0.0))
            if np.linalg.norm(step) <= tol * (tol + np.linalg.norm(w)):
                return done("step", w, cost)
            trial = w + step
            if optimistic:
                new_cost, new_H, new_Jtr = full(trial)
                counts["full_passes"] += 1
                if not (np.isfinite(new_H).all() and np.isfinite(new_Jtr).all()):
                    new_cost = np.inf  # a point whose normal equations overflow is rejected
            else:
                new_cost = cost_only(trial)
                counts["cost_passes"] += 1
            predicted = float(-Jtr @ step + mu * step @ (diag * step))
            gain = (cost - new_cost) / predicted if predicted > 0 else -1.0
            if np.isfinite(new_cost) and gain > 0:
                break
            mu *= nu
            nu *= 2.0
            optimistic = False
        reduction = cost - new_cost
        if not optimistic:
            new_cost, new_H, new_Jtr = full(trial)
            counts["full_passes"] += 1
            if not (np.isfinite(new_H).all() and np.isfinite(new_Jtr).all()):
                return done("non-finite", w, cost)  # stay at the last point that had them
        counts["accepted"] += 1
        w, cost, H, Jtr = trial, new_cost, new_H, new_Jtr
        diag = np.maximum(diag, np.diag(H))  # MINPACK: the scaling only grows
        mu *= max(1.0 / 3.0, 1.0 - (2.0 * gain - 1.0) ** 3)
        nu = 2.0
        optimistic = True
        if reduction <= tol * cost:
            return done("cost", w, cost)
