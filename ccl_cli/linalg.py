"""Batched linear algebra shared by the learners (stacks are the leading axis)."""

from __future__ import annotations

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
    return float(np.var(Y, axis=0, ddof=ddof).sum())


def eigen_lstsq(M: np.ndarray, r: np.ndarray, cutoff: float, absolute: bool = False) -> np.ndarray:
    """Solve the symmetric normal equations ``M w = r`` by eigen-decomposition.

    Eigenvalues of ``M`` below ``cutoff · max(eig)`` (or below ``cutoff`` itself with
    ``absolute``, the original library's rule) are discarded (a regularised
    pseudo-inverse, ALGORITHMS.md §4–§5). ``M`` is (..., d, d), ``r`` (..., d).
    """
    vals, vecs = np.linalg.eigh(M)
    top = np.maximum(vals[..., -1:], np.finfo(float).tiny)
    threshold = cutoff if absolute else cutoff * top
    inv = np.where(vals > threshold, 1.0 / np.where(vals > 0, vals, 1.0), 0.0)
    coef = np.einsum("...ij,...i->...j", vecs, r) * inv
    return np.einsum("...ij,...j->...i", vecs, coef)
