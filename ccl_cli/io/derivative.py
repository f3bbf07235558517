"""Velocities of recorded positions: U = dX/dt by a local polynomial on the real stamps.

At each sample a polynomial of degree ``order`` is fitted by least squares to ``window``
neighbouring samples (centred; shifted at the ends of a demonstration) on their real,
possibly non-uniform timestamps; its first-order coefficient is the derivative (the
Savitzky–Golay idea without the uniform grid). Fits never reach across demonstrations,
so a cut or a gap is never differentiated across.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.options import ActionOptions
from ccl_cli.learn import defaults


def window_for_rate(rate: float, order: int = 2) -> int:
    """The default derivative window at ``rate`` Hz: the odd number of samples spanning
    ±:data:`~ccl_cli.learn.defaults.DERIVATIVE_HALF_SPAN_S` (9 at 50 Hz, 81 at 500 Hz), at least
    order + 2 and at most :data:`~ccl_cli.learn.defaults.DERIVATIVE_MAX_WINDOW`."""
    half = int(round(defaults.DERIVATIVE_HALF_SPAN_S * float(rate))) if np.isfinite(rate) else 0
    window = 2 * half + 1
    lo = order + 2 + (order + 2 + 1) % 2  # the smallest odd window > order + 1
    hi = defaults.DERIVATIVE_MAX_WINDOW
    return int(min(max(window, lo), hi))


def default_window(t: np.ndarray, demo: np.ndarray, order: int = 2) -> tuple[int, float]:
    """(window, rate): :func:`window_for_rate` at the median sampling rate of t (N,) s
    within demonstrations (the rate is nan when no two samples share one)."""
    dt = np.diff(t)[demo[1:] == demo[:-1]]
    dt = dt[dt > 0]
    rate = float(1.0 / np.median(dt)) if len(dt) else float("nan")
    return window_for_rate(rate, order), rate


def derive_actions(t: np.ndarray, X: np.ndarray, demo: np.ndarray, action: ActionOptions | None,
                   paced: bool = False) -> tuple[np.ndarray, dict[str, Any]]:
    """Velocities of the states, dX/dt (N, d), by :func:`local_polynomial_derivative` with
    the ``action`` window and order; without a window, :func:`default_window` chooses it
    from the sampling rate — or, when the stamps are made from an assumed rate (``paced``),
    :data:`~ccl_cli.learn.defaults.DERIVATIVE_PACED_WINDOW` samples, so that the assumed rate
    only rescales U. t (N,) s, X (N, d), demo (N,) → (U, metadata saying what was used and why)."""
    action = action or ActionOptions()
    order, window = action.order, action.window
    if window is None and paced:
        window = max(defaults.DERIVATIVE_PACED_WINDOW, order + 2 + (order + 3) % 2)
        why = (f"default without stamps: {window} samples, whatever rate is assumed (an assumed rate "
               "only rescales the velocities)")
    elif window is None:
        window, rate = default_window(t, demo, order)
        why = (f"default: ±{defaults.DERIVATIVE_HALF_SPAN_S:g} s at the median rate "
               f"{rate:.4g} Hz" + (f" (capped at {defaults.DERIVATIVE_MAX_WINDOW} samples)"
                                   if window == defaults.DERIVATIVE_MAX_WINDOW else ""))
    else:
        why = "data.action.window"
    U = local_polynomial_derivative(t, X, demo, window, order)
    return U, {"derived": "local polynomial", "window": int(window), "order": int(order),
               "window_rule": why}


def local_polynomial_derivative(t: np.ndarray, Y: np.ndarray, demo: np.ndarray, window: int = 9,
                                order: int = 2, chunk: int = 8192) -> np.ndarray:
    """dY/dt by a degree-``order`` polynomial fitted to ``window`` neighbouring samples
    (centred; shifted at the ends of each demonstration), on the real timestamps.

    t (N,) seconds, Y (N, d), demo (N,) → (N, d). Each sample's slope filter c (window,)
    — row 1 of the least-squares solution (VᵀV)⁻¹Vᵀ, V the (window, order+1) Vandermonde
    matrix of its neighbours' stamps relative to its own, scaled to [−1, 1] — is solved for
    ``chunk`` samples at a time (memory O(chunk · window · order)); dY/dt_n = Σ_j c_j y_{n+j}
    is summed over the window's offsets (a pass per offset, not a gather of every window).
    """
    n = len(t)
    if isinstance(order, bool) or not isinstance(order, int | np.integer) or order < 1:
        raise InputError(f"derivative order must be an integer ≥ 1 (the first derivative is its "
                         f"coefficient), got {order!r}")
    if isinstance(window, bool) or not isinstance(window, int | np.integer) or window < order + 1 \
            or window % 2 == 0:
        raise InputError(f"derivative window must be odd and > order ({order}), got {window!r}")
    starts_of = np.flatnonzero(np.r_[True, demo[1:] != demo[:-1]])
    ends_of = np.r_[starts_of[1:], n]
    seg = np.cumsum(np.r_[True, demo[1:] != demo[:-1]]) - 1
    lo, hi = starts_of[seg], ends_of[seg]
    sizes = hi - lo
    if sizes.min() < order + 1:
        raise InputError(f"a demonstration has {int(sizes.min())} samples; deriving with order {order} "
                         f"needs at least {order + 1}")
    w = np.minimum(window, sizes)  # per-sample window (short demos use all their samples)
    start = np.clip(np.arange(n) - w // 2, lo, hi - w)
    out = np.empty((n, Y.shape[1]))
    for s in range(0, n, chunk):  # chunks of samples, each a batch
        e = min(s + chunk, n)
        width = int(w[s:e].max())
        idx = np.minimum(start[s:e, None] + np.arange(width), hi[s:e, None] - 1)
        valid = np.arange(width) < w[s:e, None]
        c = _slope_filters(t, idx, valid, np.arange(s, e), order)
        # centred full windows read Y at one shift per offset; the others gather their window
        centred = (start[s:e] == np.arange(s, e) - width // 2) & (w[s:e] == width)
        if centred.any():
            a, b = s + int(np.argmax(centred)), e - int(np.argmax(centred[::-1]))
            acc = np.zeros((b - a, Y.shape[1]))
            first = a - width // 2
            taps = np.ascontiguousarray(c[a - s:b - s].T)[:, :, None]  # (W, b − a, 1)
            for k in range(width):  # a loop over the window's offsets, not samples
                acc += taps[k] * Y[first + k:first + k + b - a]
            out[a:b] = acc
        rest = np.flatnonzero(~centred)
        if len(rest):
            out[s + rest] = np.einsum("mw,mwd->md", c[rest] * valid[rest], Y[idx[rest]])
    return out


def _slope_filters(t: np.ndarray, idx: np.ndarray, valid: np.ndarray, at: np.ndarray, order: int
                   ) -> np.ndarray:
    """The slope filters c (M, W) of the samples ``at`` (M,) over their neighbours idx (M, W)
    where valid: c = row 1 of pinv(V)/scale, V_jk = (τ_j/scale)^k valid_j, τ_j = t_idx − t_at,
    scale = max|τ|. Solved by the normal equations VᵀV g = e₁ (VᵀV_ik = Σ_j u_j^(i+k), the
    moments of u = τ/scale), by pinv where VᵀV is singular."""
    tau = (t[idx] - t[at, None]) * valid
    scale = np.maximum(np.abs(tau).max(1, keepdims=True), 1e-12)
    u = tau / scale
    powers = [valid.astype(float)]  # valid · u^k, k = 0 … 2·order
    for _ in range(2 * order):
        powers.append(powers[-1] * u)
    moments = np.stack([p.sum(1) for p in powers], 1)  # (M, 2·order + 1)
    k = np.arange(order + 1)
    e1 = np.zeros((len(u), order + 1, 1))
    e1[:, 1] = 1.0
    try:
        g = np.linalg.solve(moments[:, k[:, None] + k[None, :]], e1)[..., 0]  # row 1 of (VᵀV)⁻¹
    except np.linalg.LinAlgError:  # a window with fewer distinct stamps than order + 1
        return np.linalg.pinv(np.stack(powers[:order + 1], 2))[:, 1, :] / scale
    c = g[:, :1] * powers[0]
    for j in range(1, order + 1):
        c += g[:, j:j + 1] * powers[j]
    return c / scale
