"""From streams to :class:`~ccl_cli.dataset.Demonstrations`.

* the action stream is interpolated onto the state's stamps (samples of the state
  outside the action's time span are dropped), or derived from the state;
* derivatives come from a local polynomial (Savitzky–Golay style) fitted by least
  squares on the real, non-uniform timestamps of a window of samples, inside each
  demonstration only — never across a gap;
* demonstrations are one per file, split on time gaps, given as time ranges, and/or cut
  into fixed windows (continuous recordings).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.learn import defaults

log = logging.getLogger("ccl")


def check_increasing(t_ns: np.ndarray, where: str) -> None:
    d = np.diff(t_ns)
    if (d <= 0).any():
        k = int(np.argmax(d <= 0)) + 1
        raise InputError(f"{where}: timestamps are not strictly increasing at sample {k} "
                         f"({int(t_ns[k - 1])} ns then {int(t_ns[k])} ns)")


DEMOS_KEYS = ("split_on_gap", "ranges", "window", "per_file")


def segment_ids(t_s: np.ndarray, demos: dict[str, Any] | None, where: str) -> np.ndarray:
    """Demo id per sample (−1 = outside every range) from the ``demos`` config.

    ``{split_on_gap: seconds}`` cuts where consecutive stamps are further apart;
    ``{ranges: [[t0, t1], ...]}`` (seconds from the first sample) keeps only those spans;
    ``{window: S}`` then cuts every resulting segment (the whole recording by default)
    into fixed windows of S seconds from its first sample, a tail shorter than S/2 joining
    the window before it. Nothing: one demonstration. t_s (N,) seconds → (N,) int.
    """
    demos = demos or {}
    unknown = set(demos) - set(DEMOS_KEYS)
    if unknown:
        raise InputError(f"{where}: demos: unknown option(s) {', '.join(sorted(unknown))} "
                         "(use split_on_gap, ranges, window or per_file)")
    n = len(t_s)
    gap = demos.get("split_on_gap")
    if demos.get("ranges") is not None:
        ids = np.full(n, -1)
        rel = t_s - t_s[0]
        ranges = demos["ranges"]
        if not isinstance(ranges, list | tuple):
            raise InputError(f"{where}: demos.ranges must be a list of [start, end] pairs, "
                             f"got {ranges!r}"[:200])
        for k, rng in enumerate(ranges):
            numbers = isinstance(rng, list | tuple) and len(rng) == 2 and all(
                isinstance(v, int | float) and not isinstance(v, bool) and np.isfinite(v) for v in rng)
            if not numbers or not rng[0] < rng[1]:
                raise InputError(f"{where}: demos.ranges[{k}] must be [start, end] (finite seconds) with "
                                 f"start < end, got {rng!r}"[:200])
            inside = (rel >= rng[0]) & (rel <= rng[1]) & (ids < 0)
            ids[inside] = k
        if (ids < 0).all():
            raise InputError(f"{where}: no samples inside demos.ranges")
    elif gap is not None:
        if isinstance(gap, bool) or not isinstance(gap, int | float) or not gap > 0:
            raise InputError(f"{where}: demos.split_on_gap must be positive seconds, got {gap}")
        ids = np.concatenate([[0], np.cumsum(np.diff(t_s) > gap)])
    else:
        ids = np.zeros(n, dtype=int)
    window = demos.get("window")
    if window is not None:
        if isinstance(window, bool) or not isinstance(window, int | float) or not window > 0:
            raise InputError(f"{where}: demos.window must be positive seconds, got {window!r}")
        ids = cut_windows(t_s, ids, float(window))
    return ids


def cut_windows(t_s: np.ndarray, ids: np.ndarray, window: float) -> np.ndarray:
    """Cut each contiguous run of equal ``ids`` (≥ 0) into windows of ``window`` seconds
    from the run's first stamp; a last window shorter than ``window``/2 joins the one
    before it; −1 stays −1. Returns consecutive ids 0, 1, ... in time order."""
    n = len(t_s)
    if n == 0:
        return ids
    start = np.r_[True, ids[1:] != ids[:-1]]
    run = np.cumsum(start) - 1
    first = np.flatnonzero(start)
    last = np.r_[first[1:], n] - 1
    rel = t_s - t_s[first][run]
    k = np.floor(rel / window).astype(int)
    span = t_s[last] - t_s[first]  # per run
    k_last = np.floor(span / window).astype(int)
    short_tail = (span - k_last * window < window / 2) & (k_last > 0)
    k = np.where((k == k_last[run]) & short_tail[run], k - 1, k)
    change = np.r_[True, (run[1:] != run[:-1]) | (k[1:] != k[:-1])]
    out = np.cumsum(change & (ids >= 0)) - 1
    return np.where(ids >= 0, out, -1)


def resegment(data: Demonstrations, demos: dict[str, Any] | None, where: str,
              masks: dict[str, list[int]] | None = None
              ) -> tuple[Demonstrations, dict[str, list[int]] | None]:
    """Apply the ``demos`` config inside each demonstration of an already assembled dataset
    (canonical HDF5): gaps, ranges (seconds from each demonstration's first sample) and
    windows. Samples outside every range are dropped. Train/test ``masks`` (lists of demo
    ids) are carried over: each new piece keeps the membership of the demonstration it came
    from. Returns the re-cut dataset and masks."""
    if not demos:
        return data, masks
    new = np.full(data.n_samples, -1)
    parent: list[int] = []
    for d in data.demo_ids:  # loop over demonstrations, not samples
        rows = np.flatnonzero(data.demo == d)
        ids = segment_ids(data.t[rows], demos, f"{where}: demo {int(d)}")
        inside = ids >= 0
        new[rows[inside]] = ids[inside] + len(parent)
        parent += [int(d)] * (int(ids.max()) + 1 if inside.any() else 0)
    keep = new >= 0
    out = data.subset(keep)
    out.demo = new[keep]
    out.metadata = {**data.metadata, "demos": dict(demos)}
    if masks:
        parent_arr = np.asarray(parent)
        masks = {name: [int(i) for i in np.flatnonzero(np.isin(parent_arr, ids))]
                 for name, ids in masks.items()}
    return out, masks


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


def derive_actions(t: np.ndarray, X: np.ndarray, demo: np.ndarray, action_cfg: dict
                   ) -> tuple[np.ndarray, dict[str, Any]]:
    """Velocities of the states, dX/dt (N, d), by :func:`local_polynomial_derivative` with
    ``action_cfg`` window/order; without a window, :func:`default_window` chooses it from
    the sampling rate. Returns (U, metadata saying what was used and why)."""
    order = action_cfg.get("order", 2)
    window = action_cfg.get("window")
    if window is None:
        window, rate = default_window(t, demo, order if isinstance(order, int) else 2)
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


def align(t_target: np.ndarray, t_source: np.ndarray, values: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Linear interpolation of ``values`` (at ``t_source``) onto ``t_target`` (int64 ns).

    Returns (values at the kept targets, boolean mask of targets inside the source span).
    """
    if len(t_target) == len(t_source) and np.array_equal(t_target, t_source):
        return values, np.ones(len(t_target), bool)  # same stamps (same topic): nothing to do
    inside = (t_target >= t_source[0]) & (t_target <= t_source[-1])
    base = t_source[0]
    ts = (t_source - base).astype(float)
    tt = (t_target[inside] - base).astype(float)
    out = np.empty((int(inside.sum()), values.shape[1]))
    for j in range(values.shape[1]):  # loop over dimensions, not samples
        out[:, j] = np.interp(tt, ts, values[:, j])
    return out, inside


def drop_nonfinite(t_ns: np.ndarray, values: np.ndarray, policy: str, where: str
                   ) -> tuple[np.ndarray, np.ndarray]:
    bad = ~np.isfinite(values).all(axis=1)
    if not bad.any():
        return t_ns, values
    if policy == "fail":
        raise InputError(f"{where}: {int(bad.sum())} samples contain NaN or inf "
                         f"(first at sample {int(np.argmax(bad))}); set data.nonfinite: drop to skip them")
    if policy != "drop":
        raise InputError(f"data.nonfinite must be drop or fail, got {policy!r}")
    log.warning("%s: dropped %d samples with NaN or inf", where, int(bad.sum()))
    return t_ns[~bad], values[~bad]
