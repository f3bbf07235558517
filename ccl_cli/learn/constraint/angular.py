"""Sequential learning of unit constraint rows whose angles are linear in features
(ALGORITHMS.md §3.2, used by "alpha" and "lambda").

For constraint k the observations are first rotated, per sample, into a frame whose
first k−1 axes are the rows already found: z_n = Q_n v_n. The new row, in that frame,
is [0_{k−1}; a(θ_n)] with θ_n = W_k β(x_n) ∈ R^{d−k} (fixing the first k−1 angles at
π/2 makes it orthogonal to the earlier rows). W_k minimises Σ_n r_n², r_n = a(θ_n)ᵀ z_n,
by Levenberg–Marquardt with the analytic Jacobian

    ∂r_n/∂W_k[i, j] = (∂a/∂θ_i(θ_n) · z_n) β_j(x_n),

whose rows vec(g_n β_nᵀ) are summed into JᵀJ and Jᵀr block by block, one pass over
the data per iteration (:func:`~ccl_cli.learn.linalg.kron_least_squares`; no N × (d−k)K matrix),

from several seeded starts (the local closed form, the best constant direction, random
ones): each start is screened for SCREEN_PASSES iterations and the best is run to
convergence (at most MAX_ITER passes). Above SEARCH_ROWS samples this search runs on a
seeded subsample of SEARCH_ROWS rows and the winner is refined by at most REFINE_PASSES
passes over all the data, so a row costs a handful of full passes. The frame is then
advanced with the Givens rotation of θ_n: Q_n ← blockdiag(I_{k−1}, R(θ_n)ᵀ) Q_n.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING

import numpy as np

from ccl_cli.learn.angles import angles_of, frame, unit_vector, unit_vector_jacobian
from ccl_cli.learn.basis import Blocks, feature_blocks, feature_cache_bytes
from ccl_cli.learn.linalg import WARM_TOL, kron_least_squares, lift_to_rows, row_chunks, total_variance

if TYPE_CHECKING:
    from ccl_cli.learn.basis import Basis

#: Default bound on the LM passes of one row (alpha's and lambda's ``max_iter``; the
#: evidence: docs/measurements.md, "The angle fits").
MAX_ITER = 200
#: LM iterations every start gets before only the best one is continued.
SCREEN_PASSES = 8
#: Above this many samples the starts of a row are searched on a seeded subsample of this
#: size and only the winner is refined on all the data (every tutorial problem is smaller).
SEARCH_ROWS = 4096
#: LM passes over all the data that refine the winner of the subsample search (the first
#: only evaluates the start; docs/measurements.md, "The angle fits").
REFINE_PASSES = 4
#: Eigenvalue cut-off of the LM steps: the angle fits keep every direction (as before).
ANGLE_CUTOFF = 1e-16


@dataclass
class AngleFit:
    """Result of fitting one row: weights W (d−k, K) and its residual statistics."""

    W: np.ndarray
    nmse: float
    cost: float


def _advance(Q: np.ndarray, k: int, theta: np.ndarray) -> np.ndarray:
    """Q ← blockdiag(I_k, R(θ)ᵀ) Q for stacks Q (N, d, d), θ (N, d−k−1)."""
    R = frame(theta)
    Q = Q.copy()
    Q[:, k:, :] = np.einsum("nji,njc->nic", R, Q[:, k:, :])
    return Q


def rows_from_weights(B: np.ndarray, weights: list[np.ndarray], d: int) -> np.ndarray:
    """Rebuild the learnt rows at features B (N, K): → (N, s, d), orthonormal per sample."""
    n = B.shape[0]
    Q = np.broadcast_to(np.eye(d), (n, d, d)).copy()
    rows = np.empty((n, len(weights), d))
    for k, W in enumerate(weights):
        theta = B @ W.T
        local = unit_vector(theta)  # (N, d−k)
        rows[:, k, :] = np.einsum("nj,njc->nc", local, Q[:, k:, :])
        if k + 1 < len(weights):
            Q = _advance(Q, k, theta)
    return rows


def _local_start(B: np.ndarray, Z: np.ndarray, X: np.ndarray, rng: np.random.Generator,
                 n_clusters: int = 36) -> np.ndarray:
    """A start for W from local closed forms.

    The states are clustered (k-means); in each cluster the best constant direction is
    the smallest eigenvector d_c of Σ z zᵀ, known up to sign. The signs s_c are
    synchronised along the maximum spanning tree of the strengths
    S_ij = κ_i κ_j e^{−‖c_i−c_j‖²/2h²} (κ the confidence 1 − λ_min/λ_next of each
    cluster), each new cluster taking the sign that makes d_i·d_j > 0 with its tree
    neighbour (the leading eigenvector of S ∘ (d_i·d_j) used before mixes far clusters
    whose directions are legitimately opposite, and failed on large samples). The last angle is
    unwrapped around its circular mean, and the per-sample angles of each sample's
    cluster are lifted into the features by ridge regression.
    """
    from ccl_cli.learn.basis import cluster_moments, kmeans_centres, pairwise_sqdist

    n, m = Z.shape
    k = int(min(n_clusters, max(1, n // (4 * m))))
    centres = kmeans_centres(X, k, seed=int(rng.integers(2**31)))
    label = np.concatenate([pairwise_sqdist(X[rows], centres).argmin(1)
                            for rows in row_chunks(n)])
    cov = cluster_moments(Z, label, k)
    vals, vecs = np.linalg.eigh(cov)
    dirs = vecs[:, :, 0]
    # a confidence in [0, 1]; a degenerate cluster (both eigenvalues ~0, the smaller one a
    # rounding error below 0) would give ±huge values that overflow the products below
    conf = np.clip(1.0 - vals[:, 0] / np.maximum(vals[:, 1], np.finfo(float).tiny), 0.0, 1.0)
    dist = pairwise_sqdist(centres, centres)
    h2 = np.median(np.sort(dist, axis=1)[:, 1]) if k > 1 else 1.0
    affinity = np.exp(-dist / (2.0 * max(h2, 1e-12)))
    dirs = dirs * _synchronised_signs(conf[:, None] * conf[None, :] * affinity, dirs)[:, None]
    theta = angles_of(dirs)
    last = theta[:, -1]
    centre = np.angle(np.sum(conf * np.exp(1j * last)))
    theta[:, -1] = centre + np.angle(np.exp(1j * (last - centre)))
    return ridge(B, theta[label]).T


def _synchronised_signs(strength: np.ndarray, dirs: np.ndarray) -> np.ndarray:
    """Signs s (k,) making neighbouring directions agree: Prim's maximum spanning tree of
    ``strength`` (k, k) from the strongest cluster; s_j = sign(d_i·d_j) s_i for its tree
    neighbour i. Loops over the k clusters (k ≤ 36), not over samples."""
    k = len(dirs)
    sign = np.ones(k)
    done = np.zeros(k, bool)
    done[int(np.argmax(np.diag(strength)))] = True
    dots = dirs @ dirs.T
    for _ in range(k - 1):
        link = np.where(done[:, None] & ~done[None, :], strength, -np.inf)
        i, j = np.unravel_index(int(np.argmax(link)), link.shape)
        sign[j] = sign[i] * (1.0 if dots[i, j] >= 0 else -1.0)
        done[j] = True
    return sign


def ridge(B: np.ndarray, Y: np.ndarray, rel: float = 1e-6) -> np.ndarray:
    """argmin_W ‖B W − Y‖² + λ‖W‖², λ = rel · tr(BᵀB)/K: a lift that stays bounded
    when the features are nearly collinear (wide normalised RBFs)."""
    G = B.T @ B
    lam = rel * np.trace(G) / G.shape[0]
    return np.linalg.solve(G + lam * np.eye(G.shape[0]), B.T @ Y)


def _residual(Z: np.ndarray):
    """r_n = a(W β_n)ᵀ z_n and g_n = ∂r_n/∂θ_n = (∂a/∂θ)ᵀ z_n for the rows of one block."""

    def residual(W: np.ndarray, rows: slice, Bc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Zc = Z[rows]
        a, J = unit_vector_jacobian(Bc @ W.T)  # (c, m), (c, m, m−1)
        return np.einsum("nj,nj->n", a, Zc), np.einsum("nji,nj->ni", J, Zc)

    return residual


def _search(B: np.ndarray, Z: np.ndarray, n_restarts: int, rng: np.random.Generator,
            max_iter: int, tol: float, X: np.ndarray | None) -> tuple[np.ndarray, float, int]:
    """The seeded starts on B (n, K), Z (n, m), screened and the best run to convergence →
    (W (m−1, K), cost, LM passes used)."""
    n, K = B.shape
    m = Z.shape[1]
    blocks = [(rows, B[rows]) for rows in row_chunks(n)]
    residual = _residual(Z)
    lift = ridge(B, np.ones(n))
    starts = [_local_start(B, Z, X, rng)] if X is not None else []
    # The best constant direction (smallest eigenvector of Σ z zᵀ), in the features.
    _, vecs = np.linalg.eigh(Z.T @ Z)
    starts.append(np.outer(angles_of(vecs[:, :1].T)[0], lift))
    while len(starts) < max(1, n_restarts):
        th = rng.uniform(0.0, np.pi, m - 1)
        starts.append(np.outer(th, lift) + rng.normal(scale=0.3, size=(m - 1, K)))
    if len(starts) == 1:
        return kron_least_squares(starts[0], lambda: blocks, residual, max_iter, tol, ANGLE_CUTOFF)
    # Screen: every start gets SCREEN_PASSES iterations, the best one is run to convergence.
    screened = [kron_least_squares(w0, lambda: blocks, residual, min(SCREEN_PASSES, max_iter), tol,
                                   ANGLE_CUTOFF)
                for w0 in starts]
    W, cost, used = min(screened, key=lambda fit: fit[1])
    if used < min(SCREEN_PASSES, max_iter):  # converged while screening
        return W, cost, used
    W, cost, more = kron_least_squares(W, lambda: blocks, residual, max(1, max_iter - used), tol,
                                       ANGLE_CUTOFF)
    return W, cost, used + more


def rotated(V: np.ndarray, B: np.ndarray, weights: list[np.ndarray]) -> np.ndarray:
    """Observations V (c, d) in the frames of the rows already learnt (``weights``, k of
    them, at features B (c, K)): z = [Q v]_{k:} → (c, d − k)."""
    k, d = len(weights), V.shape[1]
    if k == 0:
        return V
    Q = np.broadcast_to(np.eye(d), (len(V), d, d)).copy()
    for j, W in enumerate(weights):
        Q = _advance(Q, j, B @ W.T)
    return np.einsum("nij,nj->ni", Q[:, k:, :], V)


def _residual_in_frames(V: np.ndarray, weights: list[np.ndarray]):
    """:func:`_residual` of the next row, its observations rotated block by block from V (N, d)
    (no N × d × d stack of frames is kept)."""

    def residual(W: np.ndarray, rows: slice, Bc: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        Zc = rotated(V[rows], Bc, weights)
        a, J = unit_vector_jacobian(Bc @ W.T)
        return np.einsum("nj,nj->n", a, Zc), np.einsum("nji,nj->ni", J, Zc)

    return residual


def _fit_row(basis: Basis, blocks: Blocks, X: np.ndarray, V: np.ndarray, weights: list[np.ndarray],
             n_restarts: int, rng: np.random.Generator, max_iter: int, tol: float, local: bool,
             start: np.ndarray | None = None, refine: int | None = None, search_rows: int | None = None
             ) -> tuple[np.ndarray, float]:
    """min_W Σ_n (a(W β_n)ᵀ z_n)² for the next row → (W (m−1, K), cost), z_n = V's sample n
    in the frames of the rows in ``weights`` (m = d − len(weights) ≥ 2).

    From ``start`` (m−1, K): Levenberg–Marquardt on all N rows, to ``tol`` (at least
    :data:`~ccl_cli.learn.linalg.WARM_TOL`) or ``max_iter`` passes — with ``refine``, at most
    that many passes from ``start`` as it is (a fit on fewer rows, refined as a subsample
    search's winner); without, from ``start`` seen through these rows
    (:func:`~ccl_cli.learn.linalg.lift_to_rows`: a fit on more rows, a fold's start). Otherwise the seeded
    starts (:func:`_search`) are searched on all rows up to ``search_rows`` (default
    :data:`SEARCH_ROWS`) samples; above it, on a seeded subsample of that many rows (local
    start, screening and the run to convergence), and the winner is then refined by LM
    passes over all N rows for at most :data:`REFINE_PASSES` passes — it starts next to the
    optimum (issue 10: full-data passes only for the winning start).
    The features come in ``blocks`` (:func:`~ccl_cli.learn.basis.feature_blocks` of X)."""
    n = len(V)
    residual = _residual_in_frames(V, weights)
    if start is not None:  # refine: from fewer rows, as is; else seen through these rows
        passes = max_iter if refine is None else max(1, min(refine, max_iter))
        W0 = start if refine is not None else lift_to_rows(start, blocks)
        W, cost, _ = kron_least_squares(W0, blocks, residual, passes, max(tol, WARM_TOL), ANGLE_CUTOFF)
        return W, cost
    limit = int(search_rows or SEARCH_ROWS)
    idx = np.arange(n) if n <= limit else np.sort(rng.choice(n, limit, replace=False))
    B = basis.transform(X[idx])
    Z = rotated(V[idx], B, weights)
    W, cost, used = _search(B, Z, n_restarts, rng, max_iter, tol, X[idx] if local else None)
    if n <= limit:
        return W, cost
    W, cost, _ = kron_least_squares(W, blocks, residual, max(1, min(REFINE_PASSES, max_iter - used)), tol,
                                    ANGLE_CUTOFF)
    return W, cost


def fit_sequence(
    basis: Basis,
    X: np.ndarray,
    V: np.ndarray,
    max_k: int,
    n_restarts: int,
    seed: int,
    max_iter: int = MAX_ITER,
    tol: float = 1e-9,
    stop_original: bool = True,
    local: bool = True,
    starts: list[np.ndarray] | None = None,
    refine: int | None = None,
) -> list[AngleFit]:
    """Learn rows one at a time on observations V (N, d) at states X (N, p) with the fitted
    feature map ``basis``; the states also place the clusters of the local start (``local``).
    ``starts``: weights to start row k from (a fit of the same basis on other rows of the same
    data; ``refine``: at most this many passes from them); rows beyond them are searched.

    nmse_k = mean(r²) / Σ var(V) (ddof = 1). With ``stop_original`` the loop stops,
    keeping the earlier rows, once nmse_k exceeds both the best so far and 1e-3
    (the original rule); the rejected fit is still returned last so callers can
    report it. Without it all ``max_k`` rows are learnt. Memory: the features are computed
    in row blocks (kept only when small, :func:`~ccl_cli.learn.basis.feature_blocks`) and the
    frames of earlier rows per block, so nothing of size N × K or N × d × d is kept.
    """
    rng = np.random.default_rng(seed)
    n = len(V)
    var = total_variance(V)
    blocks = feature_blocks(basis, X, cache_bytes=feature_cache_bytes(X, V))
    fits: list[AngleFit] = []
    best = np.inf
    for k in range(max_k):
        start = starts[k] if starts is not None and k < len(starts) else None
        W, cost = _fit_row(basis, blocks, X, V, [f.W for f in fits], n_restarts, rng, max_iter, tol, local,
                           start, refine)
        nmse = (cost / n) / var if var > 0 else np.inf
        fits.append(AngleFit(W, float(nmse), cost))
        if stop_original and k > 0 and nmse > best and nmse > 1e-3:
            break
        best = min(best, nmse)
    return fits
