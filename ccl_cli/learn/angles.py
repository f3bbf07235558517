"""Unit vectors written in hyperspherical angles (ALGORITHMS.md §3.1, §3.2).

For θ ∈ R^{d−1} the unit vector a(θ) ∈ R^d is

    a_1 = cos θ_1,  a_i = cos θ_i Π_{j<i} sin θ_j  (i = 2..d−1),  a_d = Π_{j≤d−1} sin θ_j.

It is the image of e_1 under the Givens rotations G_{d−1}(θ_{d−1}) ··· G_1(θ_1),
where G_i(t) rotates the (i, i+1) plane; :func:`frame` returns that rotation, whose
first column is a(θ) and whose other columns complete an orthonormal basis that
varies smoothly with θ (used to learn further constraints orthogonal to earlier ones).
Everything is batched over a leading sample axis.
"""

from __future__ import annotations

import numpy as np


def unit_vector(theta: np.ndarray) -> np.ndarray:
    """a(θ): (N, d−1) → (N, d)."""
    theta = np.atleast_2d(theta)
    n, m = theta.shape
    s, c = np.sin(theta), np.cos(theta)
    prefix = np.ones((n, m + 1))
    prefix[:, 1:] = np.cumprod(s, axis=1)  # prefix[:, i] = Π_{j<i} sin θ_j
    a = np.empty((n, m + 1))
    a[:, :m] = c * prefix[:, :m]
    a[:, m] = prefix[:, m]
    return a


def unit_vector_jacobian(theta: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """a(θ) and ∂a/∂θ: (N, d−1) → ((N, d), (N, d, d−1)).

    ∂a_i/∂θ_k = −sin θ_i Π_{j<i} sin θ_j for k = i, cos θ_i cos θ_k Π_{j<i, j≠k} sin θ_j
    for k < i (with cos θ_d := 1), and 0 for k > i. Products that skip θ_k are formed
    from prefix and suffix products, so no division by sin θ_k occurs.
    """
    theta = np.atleast_2d(theta)
    n, m = theta.shape
    d = m + 1
    s, c = np.sin(theta), np.cos(theta)
    a = unit_vector(theta)
    cos_ext = np.ones((n, d))
    cos_ext[:, :m] = c
    jac = np.zeros((n, d, m))
    for i in range(d):  # loops over dimensions only (d ≤ ~10), never over samples
        if i < m:
            jac[:, i, i] = -s[:, i] * np.prod(s[:, :i], axis=1)
        for k in range(min(i, m)):
            others = np.prod(s[:, :k], axis=1) * np.prod(s[:, k + 1 : i], axis=1)
            jac[:, i, k] = cos_ext[:, i] * c[:, k] * others
    return a, jac


def angles_of(a: np.ndarray) -> np.ndarray:
    """Hyperspherical angles of unit vectors: (N, d) → (N, d−1), inverse of :func:`unit_vector`."""
    a = np.atleast_2d(a)
    d = a.shape[1]
    tail = np.sqrt(np.cumsum((a[:, ::-1] ** 2), axis=1))[:, ::-1]  # ‖a_{i:}‖
    theta = np.empty((a.shape[0], d - 1))
    for i in range(d - 2):
        theta[:, i] = np.arctan2(tail[:, i + 1], a[:, i])
    theta[:, d - 2] = np.arctan2(a[:, d - 1], a[:, d - 2])
    return theta


def frame(theta: np.ndarray) -> np.ndarray:
    """Rotation R(θ) = G_{d−1}(θ_{d−1}) ··· G_1(θ_1): (N, d−1) → (N, d, d), R e_1 = a(θ)."""
    theta = np.atleast_2d(theta)
    n, m = theta.shape
    d = m + 1
    R = np.broadcast_to(np.eye(d), (n, d, d)).copy()
    for i in range(m):  # left-multiply by G_i: rows i, i+1 mix
        ci, si = np.cos(theta[:, i])[:, None], np.sin(theta[:, i])[:, None]
        ri, rj = R[:, i, :].copy(), R[:, i + 1, :].copy()
        R[:, i, :] = ci * ri - si * rj
        R[:, i + 1, :] = si * ri + ci * rj
    return R
