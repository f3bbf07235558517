"""Noise of sampled trajectories, estimated from differences in time.

White noise of variance σ² on samples y_n gives second differences
Δ²y_n = y_{n+1} − 2y_n + y_{n−1} of variance 6σ², while smooth motion adds little at the
sampling rates of recordings. The median absolute value is robust to that motion and to
rare outliers: σ̂² = (median|Δ²y| / 0.6745)² / 6 (0.6745: the median of |z| for a standard
normal z).

Velocities derived from positions by a local polynomial (the readers' derivative,
:func:`ccl_cli.io.derivative.local_polynomial_derivative`) carry the positions' noise through
the slope filter c of that fit: on uniform stamps dt apart, σ²_u = σ²_x Σc².

Shapes: Y (N, d) samples grouped by ``demo`` (N,) (contiguous, in time order); direction
rows (k, d) constant, or (N, k, d) one set per sample.
"""

from __future__ import annotations

import numpy as np

from ccl_cli.learn.defaults import DERIVATIVE_HALF_SPAN_S, DERIVATIVE_MAX_WINDOW

#: Median of |z| for a standard normal z: σ = median|z·σ| / MAD_NORMAL.
MAD_NORMAL = 0.6744897501960817


def second_differences(Y: np.ndarray, demo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Δ²y_n (M, d) for every n whose neighbours n ± 1 share its demonstration, and those
    centre indices n (M,)."""
    Y = np.asarray(Y, dtype=float)
    if len(Y) < 3:
        return np.zeros((0, Y.shape[1])), np.zeros(0, dtype=int)
    inside = (demo[2:] == demo[1:-1]) & (demo[1:-1] == demo[:-2])
    d2 = Y[2:] - 2 * Y[1:-1] + Y[:-2]  # slices: no gathered copies of Y
    if inside.all():
        return d2, np.arange(1, len(Y) - 1)
    return d2[inside], np.flatnonzero(inside) + 1


def robust_std(r: np.ndarray, axis: int = 0) -> np.ndarray:
    """σ̂ = median|r| / MAD_NORMAL of zero-mean residuals r along ``axis``."""
    if r.shape[axis] == 0:
        return np.zeros(np.delete(r.shape, axis))
    if r.ndim == 2 and axis in (0, -2):  # one partition per column, of a contiguous copy
        return np.array([np.median(np.abs(r[:, j]), overwrite_input=True)
                         for j in range(r.shape[1])], dtype=float) / MAD_NORMAL
    return np.median(np.abs(r), axis=axis) / MAD_NORMAL


def white_noise_var(Y: np.ndarray, demo: np.ndarray, rows: np.ndarray | None = None) -> np.ndarray:
    """Variance of white noise on Y (N, d) from its second differences, (median|Δ²|/0.6745)²/6:
    per dimension (d,) without ``rows``; along each direction a_k, the noise of aᵀy, (k,)
    with ``rows`` (k, d) or per-sample rows (N, k, d) (applied at each centre sample; rows need
    not be unit vectors)."""
    d2, centre = second_differences(Y, demo)
    if rows is None:
        proj = d2
    elif np.ndim(rows) == 2:
        proj = d2 @ np.asarray(rows, float).T
    else:
        proj = np.einsum("mkd,md->mk", np.asarray(rows, float)[centre], d2)
    return robust_std(proj) ** 2 / 6.0


def slope_filter(dt: float, window: int, order: int = 2) -> np.ndarray:
    """Weights c (window,) with dy/dt ≈ Σ_j c_j y_{n+j−window//2}: the slope of a degree-``order``
    polynomial fitted to ``window`` samples dt apart (the readers' derivative, centred)."""
    k = np.arange(window) - window // 2
    vander = (k[:, None] * dt) ** np.arange(order + 1)[None, :]
    return np.linalg.pinv(vander)[1]


def derived_noise_var(X: np.ndarray, demo: np.ndarray, dt: float, window: int, order: int = 2,
                      rows: np.ndarray | None = None) -> np.ndarray:
    """Noise variance of velocities derived from positions X (N, d) by the local polynomial
    (``window``, ``order``) on stamps ``dt`` apart: the positions' white-noise variance (per
    dimension, or along ``rows`` as in :func:`white_noise_var`) times Σc²."""
    gain = float((slope_filter(dt, window, order) ** 2).sum())
    return white_noise_var(X, demo, rows) * gain


def default_window(dt: float, order: int = 2) -> int:
    """The readers' default derivative window for stamps ``dt`` s apart: the odd number of
    samples spanning ±DERIVATIVE_HALF_SPAN_S, at least order + 2, at most DERIVATIVE_MAX_WINDOW."""
    half = int(round(DERIVATIVE_HALF_SPAN_S / dt)) if dt > 0 and np.isfinite(dt) else 0
    lowest = order + 2 + (order + 3) % 2
    return int(min(max(2 * half + 1, lowest), DERIVATIVE_MAX_WINDOW))
