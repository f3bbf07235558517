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


def derive_actions(t: np.ndarray, X: np.ndarray, demo: np.ndarray, action: ActionOptions | None
                   ) -> tuple[np.ndarray, dict[str, Any]]:
    """Velocities of the states, dX/dt (N, d), by :func:`local_polynomial_derivative` with
    the ``action`` window and order; without a window, :func:`default_window` chooses it
    from the sampling rate. t (N,) s, X (N, d), demo (N,) → (U, metadata saying what was
    used and why)."""
    action = action or ActionOptions()
    order, window = action.order, action.window
    if window is None:
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

    t (N,) seconds, Y (N, d), demo (N,) → (N, d). Samples are solved as batches of small
    least-squares problems, ``chunk`` at a time (memory O(chunk · window · order)).
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
    powers = np.arange(order + 1)
    out = np.empty((n, Y.shape[1]))
    for s in range(0, n, chunk):  # chunks of samples, each a batch
        r = slice(s, min(s + chunk, n))
        wr = w[r]
        offsets = np.arange(int(wr.max()))
        idx = np.minimum(start[r, None] + offsets[None, :], hi[r, None] - 1)
        valid = offsets[None, :] < wr[:, None]
        tau = (t[idx] - t[r, None]) * valid
        scale = np.maximum(np.abs(tau).max(1, keepdims=True), 1e-12)
        V = (tau / scale)[:, :, None] ** powers[None, None, :] * valid[:, :, None]
        coef = np.linalg.pinv(V) @ (Y[idx] * valid[:, :, None])  # (c, order+1, d)
        out[r] = coef[:, 1, :] / scale
    return out
