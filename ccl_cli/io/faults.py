"""Sensor faults in a recording, found — and repaired where the repair can be known — on its
positions and stamps, before velocities are derived from them.

* :func:`hemisphere_flips` — a magnetic tracker (Trakstar, Polhemus) reports positions
  mirrored through its transmitter, x → −x, while the sensor is in the other hemisphere: a
  stretch with a jump of 2‖x‖ at each end. Repaired by mirroring back (or dropped).
* :func:`spikes` — isolated outliers in states (or recorded actions). Dropped.
* :func:`stamp_faults` — duplicated samples, repeated or out-of-order stamps, clock steps
  (a jump of the stamps the positions do not show) and gaps (lost samples or pauses).
  Duplicates dropped, bad stamps and clock steps re-stamped, gaps reported.
* :func:`repeated_poses` — a sensor that updates more slowly than it is logged (a tracker read
  at 417 Hz that updates at 29 Hz) repeats each pose until the next: the repeats are dropped, the
  first sample of each pose kept (velocities then come from the poses at the sensor's rate,
  not from runs of zero motion between jumps).
* :func:`force_bias` — a force/torque channel that reads a constant offset where the tool is
  free. Reported, never removed (what the sensor should read is not known).
* :func:`clean_positions` — repeated poses, stamps, then flips, then spikes, as a reader would
  call them.

Nothing loops over samples: the passes over positions run in blocks of samples (each with
the neighbours its stencil reaches), spread over the cores (:mod:`ccl_cli.io.blockwise`), so
their temporaries are (BLOCK_ROWS, d) whatever N; what a check keeps of a whole recording is
(N,) per sample, plus the residuals whose robust scale :func:`spikes` needs. Shapes: t (N,) s,
X (N, d), demo (N,) ids of contiguous demonstrations. Each function returns :class:`Finding` s: the kind,
the samples concerned (a mask, in the indices of the arrays it was given), what was done,
and ``as_dict`` with count, [start, stop) index ranges and time ranges for the report.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.dataset import Repair
from ccl_cli.errors import ConfigError
from ccl_cli.io.blockwise import each_block
from ccl_cli.learn.noise import MAD_NORMAL, robust_std, white_noise_var

#: A flip boundary: the jump ‖x_n − x̂_n‖ (x̂_n = 2x_{n−1} − x_{n−2}) exceeds FLIP_RATIO × (the
#: mismatch of the mirrored sample, ‖x_n + x̂_n‖, + the median ‖Δ²x‖ of the recording).
FLIP_RATIO = 20.0
#: A spike: its residual from the cubic through its two neighbours on each side exceeds
#: SPIKE_Z robust standard deviations of those residuals (in some dimension), is the largest
#: among its neighbours' and has their opposite sign (thresholds of this module: measured by
#: ``benchmarks/bench_recordings.py --only faults``).
SPIKE_Z = 8.0
#: A spike's two neighbours carry residuals alike (both −⅔ of it); a step's (a jump that stays,
#: e.g. demonstrations joined without ids) differ threefold: the smaller is at least STEP_RATIO
#: of the larger for a spike.
STEP_RATIO = 0.5
#: The five samples of a spike test span at most this many median periods.
SPIKE_SPAN = 6.0
#: A sample off the cubic through its neighbours only along that curve — where the motion would
#: have been up to two samples earlier or later — is a stamp or pacing error (the recording's own
#: timing), no spike: it lies on the path its neighbours trace. Sought only where the motion of one
#: period exceeds PATH_MOTION noise standard deviations (slower, a timing error moves a sample less
#: than its noise, and the path is the noise's).
PATH_MOTION = 2.0
#: The noise of a quantised value: the standard deviation of rounding to its resolution q,
#: q/√12, times the residual's gain over white noise (≈ 1.39, :func:`spikes`).
ROUNDING = 1.39 / np.sqrt(12.0)
#: A spike lies off that path by more than the motion of this many periods (½‖x_{n+1} − x_{n−1}‖):
#: a smooth, nearly noise-free log (positions from joint encoders, filtered or resampled) has
#: residuals many times its tiny noise that are still a small part of one period's motion.
SPIKE_MOTION = 1.0
#: Stamp intervals beyond GAP_PERIODS periods + GAP_JITTER robust spreads of the intervals
#: are gaps (or clock steps).
GAP_PERIODS = 1.5
GAP_JITTER = 6.0
#: A gap is a clock step when the positions moved across it as in one period while the
#: velocity on either side (over VELOCITY_SPAN_S seconds each side) exceeds MOTION_Z times its
#: noise and, had the gap's time passed, would have moved them by MOTION_Z × their noise more.
MOTION_Z = 5.0
VELOCITY_SPAN_S = 0.16
#: Repeated poses: at least HELD_SHARE of the samples repeat the one before them exactly (every
#: coordinate), there are at least HELD_MIN_POSES new poses, and the new poses come at a steady
#: period P (robust spread of their intervals below HELD_STEADY · P): the sensor's update period.
#: A quantised sensor at rest or crawling repeats its values too, but its changes come when the
#: motion crosses a count, not at a period.
HELD_SHARE = 0.5
HELD_MIN_POSES = 20
HELD_STEADY = 0.25
#: Force bias: reported when the median of a channel at rest differs from zero by more than
#: BIAS_Z standard errors and by more than half the channel's noise.
BIAS_Z = 5.0
#: Seconds at the start and end of each demonstration taken as free of contact.
FREE_EDGE_S = 0.5
#: What :func:`clean_positions` does with hemisphere flips, and the action it reports.
FLIP_ACTIONS = {"mirror": "mirrored", "drop": "dropped", "keep": "reported"}


def _median(values: np.ndarray) -> float:
    """``np.median`` of the 1-D float array ``values`` (n ≥ 1), partitioned in place: the same
    partition and mean of the middle one or two, NaN when one is NaN; without the masked-array
    module ``np.median`` imports to check for NaN (15 ms of a short command's start)."""
    n = values.size
    middle = [n // 2 - 1, n // 2] if n % 2 == 0 else [n // 2]
    values.partition([*middle, -1])  # the last place: the largest value, NaN if there is one
    if np.isnan(values[-1]):
        return float("nan")
    return float(np.mean(values[middle[0]:middle[-1] + 1]))


def _count_runs(mask: np.ndarray) -> int:
    """The number of runs of True in ``mask`` (N,): its rising edges."""
    m = np.asarray(mask, dtype=bool)
    return int(np.count_nonzero(m[:1]) + np.count_nonzero(m[1:] & ~m[:-1]))


def runs(mask: np.ndarray) -> np.ndarray:
    """[start, stop) index pairs (R, 2) of the runs of True in ``mask`` (N,)."""
    edges = np.diff(np.r_[0, np.asarray(mask, dtype=np.int8), 0])
    return np.stack([np.flatnonzero(edges == 1), np.flatnonzero(edges == -1)], 1)


@dataclass
class Finding:
    """One kind of fault found in a recording.

    ``mask`` (N,) marks the samples concerned; ``count`` the events (by default the runs of
    ``mask``); ``action`` what was done: ``mirrored``, ``dropped``, ``restamped`` or
    ``reported``; ``detail`` numbers for the report (JSON-serialisable)."""

    kind: str
    mask: np.ndarray
    action: str
    detail: dict[str, Any] = field(default_factory=dict)
    count: int | None = None

    def __post_init__(self) -> None:
        if self.count is None:
            self.count = _count_runs(self.mask)

    def __bool__(self) -> bool:
        return bool(self.count)

    def as_dict(self, t: np.ndarray) -> dict[str, Any]:
        """kind, count, n_samples, action, ranges ([start, stop) indices), times (stamps of the
        first and last sample of each range, s) and the detail."""
        r = runs(self.mask)
        return {"kind": self.kind, "count": int(self.count), "n_samples": int(self.mask.sum()),
                "action": self.action, "ranges": r.tolist(),
                "times": [[float(t[a]), float(t[b - 1])] for a, b in r], **self.detail}


def _demo_bounds(demo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """For every sample the [start, stop) indices of its demonstration, (N,) each."""
    n = len(demo)
    new = np.r_[True, demo[1:] != demo[:-1]]
    starts = np.flatnonzero(new)
    seg = np.cumsum(new) - 1
    return starts[seg], np.r_[starts[1:], n][seg]


def _per_demo_cumsum(values: np.ndarray, demo: np.ndarray) -> np.ndarray:
    """Cumulative sum of ``values`` (N,) restarting at each demonstration."""
    total = np.cumsum(values)
    start, _ = _demo_bounds(demo)
    return total - np.r_[0, total][start]


def _rows(X: np.ndarray, s: int, e: int) -> np.ndarray:
    """Samples [s, e) of X (N, d) as a contiguous (d, e − s) block: one copy, after which every
    operation runs along the samples (a transposed view steps over d values per element)."""
    return np.ascontiguousarray(X[s:e].T)


# -- hemisphere flips --------------------------------------------------------------------
def _flip_errors(X: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """At every centre n = 1 … N−2 of X (N, d): ‖Δ²x_n‖ = ‖x_{n+1} − x̂_{n+1}‖ and
    ‖x_{n+1} + x̂_{n+1}‖, x̂_{n+1} = 2x_n − x_{n−1}, each (N − 2,); computed in blocks."""
    n = len(X)
    e_same, e_flip = np.empty(n - 2), np.empty(n - 2)

    def block(s: int, e: int) -> None:
        rows = _rows(X, s - 1, e + 1)
        before, here, after = rows[:, :-2], rows[:, 1:-1], rows[:, 2:]
        with np.errstate(over="ignore", invalid="ignore"):  # values near the float limit: inf or nan, no flip
            twice = 2 * here
            d2 = np.subtract(after, twice)
            d2 += before
            np.sqrt(np.multiply(d2, d2, out=d2).sum(0), out=e_same[s - 1:e - 1])  # rows summed in order
            twice -= before  # x̂ (the prediction), in place
            twice += after  # x_{n+1} + x̂
            np.sqrt(np.multiply(twice, twice, out=twice).sum(0), out=e_flip[s - 1:e - 1])

    each_block(block, 1, n - 1)
    return e_same, e_flip


def hemisphere_flips(X: np.ndarray, demo: np.ndarray, ratio: float = FLIP_RATIO,
                     action: str = "mirrored") -> Finding:
    """Stretches of positions X (N, d) mirrored through the origin (the transmitter).

    At a flip's ends the sample jumps by ~2‖x‖ from the linear prediction x̂_n = 2x_{n−1} −
    x_{n−2}, while the mirrored sample −x_n continues it: a boundary is where
    ‖x_n − x̂_n‖ > ``ratio`` (‖x_n + x̂_n‖ + s), s the median ‖Δ²x‖ of the recording. Between
    boundaries the samples alternate between the two hemispheres; within each demonstration
    the hemisphere holding fewer samples is the mirrored one (a recording mirrored throughout
    obeys the same constraints). Positions within ~10 (s + noise) of the origin flip without a
    detectable jump and are not found. ``mask`` marks the mirrored samples; ``detail`` gives
    the largest jump at a boundary (in the positions' unit).
    """
    X = np.asarray(X, dtype=float)
    demo = np.asarray(demo)
    n = len(X)
    mask = np.zeros(n, dtype=bool)
    none = Finding("hemisphere_flip", mask, action, {"max_jump": 0.0})
    if n < 3:
        return none
    # centres n − 1 whose neighbours share their demonstration (the boundary is at n)
    inside = (demo[2:] == demo[1:-1]) & (demo[1:-1] == demo[:-2])
    if not inside.any():
        return none
    e_same, e_flip = _flip_errors(X)
    if not inside.all():
        e_same, e_flip = e_same[inside], e_flip[inside]
    scale = _median(e_same.copy())
    is_edge = e_same > ratio * (e_flip + scale)
    if not is_edge.any():
        return none
    boundary = np.zeros(n, dtype=np.int64)
    boundary[np.flatnonzero(inside)[is_edge] + 2] = 1
    side = _per_demo_cumsum(boundary, demo) % 2  # 0: the hemisphere the demonstration starts in
    _, inverse = np.unique(demo, return_inverse=True)
    share = np.bincount(inverse, weights=side) / np.bincount(inverse)
    mirrored_side = (share > 0.5).astype(int)[inverse]  # the minority side is the mirrored one
    mask = side != mirrored_side
    return Finding("hemisphere_flip", mask, action, {"max_jump": float(e_same[is_edge].max())})


def unflip(X: np.ndarray, flips: Finding) -> np.ndarray:
    """X (N, d) with the samples of a :func:`hemisphere_flips` finding mirrored back."""
    return np.where(flips.mask[:, None], -X, X)


# -- spikes --------------------------------------------------------------------------------
#: The neighbours of a spike test, relative to the sample tested.
_STEPS = (-2, -1, 1, 2)


def _cubic_weights(t: np.ndarray, s: int, e: int) -> np.ndarray:
    """Lagrange weights w (4, e − s) of the cubic through samples n ± 1, n ± 2 evaluated at
    t_n, for n in [s, e): w_j = Π_{m≠j} (0 − τ_m) / (τ_j − τ_m), τ_j = t_{n+step_j} − t_n
    (inf or nan where two stamps coincide)."""
    tn = [t[s + k:e + k] - t[s:e] for k in _STEPS]
    w = np.empty((4, e - s))
    with np.errstate(divide="ignore", invalid="ignore", over="ignore"):
        for j in range(4):  # four rows, not a loop over samples
            o = [tn[m] for m in range(4) if m != j]
            w[j] = -(o[0] * o[1] * o[2]) / ((tn[j] - o[0]) * (tn[j] - o[1]) * (tn[j] - o[2]))
    return w


def _cubic_residuals(Y: np.ndarray, t: np.ndarray, demo: np.ndarray, period: float | None = None
                     ) -> tuple[np.ndarray, np.ndarray, float]:
    """r_n = y_n − ŷ_n, ŷ_n the cubic through samples n ± 1, n ± 2 at their stamps, as R
    (d, N) (one row per dimension; 0 where n is not tested), ``tested`` (N,): the n whose
    four neighbours share its demonstration and lie within SPIKE_SPAN periods of each other
    (not across a gap), with finite weights, and max |Y| (NaN if Y holds one; 0 for N < 5).
    ``period``: the median positive interval of t, when the caller has it. Computed in blocks."""
    n, d = Y.shape
    R = np.zeros((d, n))
    tested = np.zeros(n, dtype=bool)
    if n < 5:
        return R, tested, 0.0
    extremes: dict[int, tuple[float, float]] = {}  # per block: max and min of its rows
    if period is None:
        period, _ = _period(np.diff(t))
    tested[2:-2] = (demo[:-4] == demo[2:-2]) & (demo[4:] == demo[2:-2]) & \
        (t[4:] - t[:-4] <= SPIKE_SPAN * period)

    def block(s: int, e: int) -> None:
        w = _cubic_weights(t, s, e)
        ok = tested[s:e] & np.isfinite(w).all(0)
        tested[s:e] = ok
        w[:, ~ok] = 0.0  # untested: no inf × y
        rows = _rows(Y, s - 2, e + 2)  # samples s − 2 … e + 1: the neighbour at step k is rows[:, 2 + k:]
        extremes[s] = (rows.max(), rows.min())  # the blocks' rows cover every sample
        b = e - s
        fit = np.multiply(w[0], rows[:, 2 + _STEPS[0]:2 + _STEPS[0] + b])
        term = np.empty_like(fit)
        for j in range(1, 4):
            fit += np.multiply(w[j], rows[:, 2 + _STEPS[j]:2 + _STEPS[j] + b], out=term)
        r = np.subtract(rows[:, 2:2 + b], fit, out=R[:, s:e])
        if not ok.all():
            r[:, ~ok] = 0.0

    each_block(block, 2, n - 2)
    top, bottom = np.array(list(extremes.values())).T
    return R, tested, max(float(top.max()), -float(bottom.min()))


def _lagrange(tau: np.ndarray, nodes: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The cubic's Lagrange weights W (K, 4, G) through the four ``nodes`` (K, 4) (the neighbours'
    times relative to the sample) at times ``tau`` (K, G), and their derivatives dW/dτ."""
    W, dW = np.empty((len(tau), 4, tau.shape[1])), np.empty((len(tau), 4, tau.shape[1]))
    with np.errstate(divide="ignore", invalid="ignore"):
        for j in range(4):  # four weights, not a loop over samples
            a, b, c = (tau - nodes[:, m, None] for m in range(4) if m != j)
            den = np.prod([nodes[:, j] - nodes[:, m] for m in range(4) if m != j], axis=0)[:, None]
            W[:, j], dW[:, j] = a * b * c / den, (b * c + a * c + a * b) / den
    return W, dW


#: Gauss–Newton steps from the best of the grid's PATH_GRID times.
PATH_GRID, PATH_STEPS = 17, 6


def _off_path(Y: np.ndarray, t: np.ndarray, k: np.ndarray, scale: np.ndarray
              ) -> tuple[np.ndarray, np.ndarray]:
    """For the samples ``k`` (K,) of Y (N, d), in units of ``scale`` (d,): how far y_n lies off
    the path of its neighbours — min over τ ∈ [t_{n−2}, t_{n+2}] of ‖y_n − P(τ)‖, P the cubic
    through samples n ± 1, n ± 2 at their stamps (a grid of PATH_GRID times, then PATH_STEPS
    Gauss–Newton steps τ ← τ + (y_n − P)·P′/‖P′‖², kept in the interval) — as the largest
    coordinate of y_n − P(τ*) (K,), and that distance over the motion of one period,
    ½‖y_{n+1} − y_{n−1}‖ (K,; inf at rest)."""
    off, ratio = np.empty(len(k)), np.empty(len(k))
    steps = np.asarray(_STEPS)

    def block(s: int, e: int) -> None:
        n = k[s:e]
        nodes = t[n[:, None] + steps] - t[n][:, None]  # (B, 4)
        near = Y[n[:, None] + steps] / scale  # (B, 4, d)
        y = Y[n] / scale
        lo, hi = nodes[:, :1], nodes[:, -1:]
        grid = lo + (hi - lo) * np.linspace(0.0, 1.0, PATH_GRID)
        W, _ = _lagrange(np.c_[np.zeros(len(n)), grid], nodes)  # τ = 0 (the sample's own stamp) first
        miss = ((y[:, None] - np.einsum("bjg,bjd->bgd", W, near)) ** 2).sum(2)
        tau = np.c_[np.zeros(len(n)), grid][np.arange(len(n)), miss.argmin(1)][:, None]
        best, r = None, None
        for _ in range(PATH_STEPS + 1):  # a few steps, not a loop over samples; the best kept
            W, dW = _lagrange(tau, nodes)
            here = y - np.einsum("bj,bjd->bd", W[..., 0], near)
            dist = (here**2).sum(1)
            if best is None:
                best, r = dist, here
            else:
                better = dist < best
                best, r = np.where(better, dist, best), np.where(better[:, None], here, r)
            slope = np.einsum("bj,bjd->bd", dW[..., 0], near)
            move = (here * slope).sum(1) / np.maximum((slope**2).sum(1), np.finfo(float).tiny)
            tau = np.clip(tau + move[:, None], lo, hi)
        motion = 0.5 * np.sqrt((((Y[n + 1] - Y[n - 1]) / scale) ** 2).sum(1))
        W, _ = _lagrange(np.zeros((len(n), 1)), nodes)
        still = motion <= PATH_MOTION  # a timing error moves the sample less than its noise there
        r[still] = (y - np.einsum("bj,bjd->bd", W[..., 0], near))[still]
        off[s:e] = np.abs(r).max(1)
        with np.errstate(divide="ignore", invalid="ignore"):
            ratio[s:e] = np.sqrt((r**2).sum(1)) / motion

    each_block(block, 0, len(k), rows=1024)
    return off, ratio


def _peaks(R: np.ndarray, scale: np.ndarray, z: float, score: np.ndarray) -> np.ndarray:
    """R (d, N) divided by ``scale`` (d,) in place (z-scores); ``score`` (N,) filled with each
    sample's largest |z|; the samples (N,) whose score exceeds ``z`` and is a peak: at least its
    neighbours' (0 beyond the ends)."""
    def z_scores(s: int, e: int) -> None:
        block = R[:, s:e]
        block /= scale[:, None]  # z-scores, in place
        score[s:e] = np.abs(block).max(0)

    each_block(z_scores, 0, R.shape[1])
    mask = score > z
    mask[1:] &= score[1:] >= score[:-1]
    mask[:-1] &= score[:-1] >= score[1:]
    return mask


def _resolution(Y: np.ndarray) -> np.ndarray:
    """The smallest nonzero change between successive values of each column of Y (N, d): (d,),
    the step of a quantised signal (an encoder's count, values written with few digits); inf
    for a column that never changes."""
    low = {-1: np.full(Y.shape[1], np.inf)}  # per block

    def block(s: int, e: int) -> None:
        step = np.abs(np.diff(_rows(Y, s, e + 1), axis=1))
        step[step == 0] = np.inf
        low[s] = step.min(1)

    each_block(block, 0, len(Y) - 1)
    return np.min(list(low.values()), axis=0)


def spikes(Y: np.ndarray, t: np.ndarray, demo: np.ndarray, z: float = SPIKE_Z, *,
           period: float | None = None) -> Finding:
    """Isolated outliers in Y (N, d) (positions, or recorded actions) sampled at t (N,).

    Each sample is compared with the cubic through its two neighbours on each side (at their
    stamps; for white noise of std σ the residual has std ≈ 1.39σ, and smooth motion adds
    O(dt⁴)); a sample is a spike when its residual exceeds ``z`` robust standard deviations
    (median|r|/0.6745 over the recording, per dimension) in some dimension and is the largest
    of its neighbours' (a spike δ leaves −⅔δ on each neighbour, alike: a step leaves −½ and −⅙
    of it, and is no spike). It must also lie off the path its neighbours trace
    (:func:`_off_path`): by more than ``z`` robust standard deviations once the sample may sit
    anywhere on the cubic between its second neighbours (a sample taken early or late, or a
    motion paced unevenly, lies on the path: timing, not a spike; sought only where the motion of
    one period exceeds PATH_MOTION noise standard deviations), and by more than SPIKE_MOTION
    times the motion of one period. Every threshold is a ratio to the recording's own noise or
    motion: the same samples are found in metres or millimetres. Bursts of adjacent outliers are
    found only in part. The first and last two samples of a demonstration are not tested.
    ``detail`` gives the largest residual in robust standard deviations. ``period``: the
    median positive interval of t, when the caller has it (else computed here).
    """
    Y, t = np.asarray(Y, dtype=float), np.asarray(t, dtype=float)
    n = len(Y)
    R, tested, extent = _cubic_residuals(Y, t, np.asarray(demo), period)
    if not tested.any():
        return Finding("spike", np.zeros(n, dtype=bool), "dropped", {"max_z": 0.0})
    # robust σ per dimension: one partition of each dimension's tested residuals (a dimension
    # per thread)
    sigma = np.empty(len(R))
    inner = slice(2, n - 2)  # the samples tested when no demonstration edge or gap interrupts
    where = inner if bool(tested[inner].all()) and not tested[:2].any() and not tested[n - 2:].any() \
        else tested  # the same residuals, without the masked copy

    def spread(s: int, e: int) -> None:
        sigma[s:e] = [_median(np.abs(row[where])) for row in R[s:e]]

    each_block(spread, 0, len(R), rows=1)
    scale = np.maximum(sigma / MAD_NORMAL, max(1e-12 * extent, np.finfo(float).tiny))  # relative: any unit
    score = np.empty(n)
    mask = _peaks(R, scale, z, score)
    if mask.any():  # the noise no finer than the values' resolution (a quantised log at rest has MAD 0)
        floor = ROUNDING * _resolution(Y)
        if (floor > scale).any():
            scale, R = np.maximum(scale, floor), R * (scale / np.maximum(scale, floor))[:, None]
            mask = _peaks(R, np.ones(len(R)), z, score)
    k = np.flatnonzero(mask)  # the few candidates: their sign test
    Z = R[:, k]
    j = np.abs(Z).argmax(0)  # the dimension of each candidate's largest residual
    centre = Z[j, np.arange(len(k))]
    # both neighbours' residuals in that dimension of the other sign, ≥ a third as large
    # (smooth motion leaves residuals of one sign on neighbouring samples)
    before = np.where(k > 0, R[j, np.maximum(k - 1, 0)], 0.0)
    after = np.where(k < n - 1, R[j, np.minimum(k + 1, n - 1)], 0.0)
    signed = (before * centre < -(centre**2) / 3) & (after * centre < -(centre**2) / 3)
    # ... and alike (a spike leaves −⅔δ on both; a step S leaves −S/2 before it and −S/6 after)
    small, large = np.minimum(np.abs(before), np.abs(after)), np.maximum(np.abs(before), np.abs(after))
    alike = signed & (small >= STEP_RATIO * large)
    # ... and off the path its neighbours trace, by more than the noise and one period's motion
    off, ratio = _off_path(Y, t, k[alike], scale)
    alike[alike] = (off > z) & (ratio > SPIKE_MOTION)
    mask[k] = alike
    return Finding("spike", mask, "dropped", {"max_z": float(score.max())})


# -- stamps ----------------------------------------------------------------------------------
def _period(dt: np.ndarray) -> tuple[float, float]:
    """(median of the positive intervals, robust spread 1.4826·MAD of them)."""
    pos = dt[dt > 0]
    if not len(pos):
        return 0.0, 0.0
    med = _median(pos)  # pos is a copy: partitioned in place
    spread = np.abs(pos - med, out=pos)
    return med, _median(spread) / MAD_NORMAL


def stamp_faults(t: np.ndarray, X: np.ndarray, demo: np.ndarray
                 ) -> tuple[list[Finding], np.ndarray, np.ndarray]:
    """Faults of the stamps t (N,) of positions X (N, d); returns (findings, repaired stamps
    (N,), keep (N,) bool).

    With P the median interval and J the robust spread of the intervals (jitter), within each
    demonstration:

    * ``duplicate_sample`` — a sample with the stamp and the position of the one before it:
      dropped (``keep`` False);
    * ``bad_stamp`` — an interval ≤ 0 or a gap, where the stamps on either side are regular
      (t_{n+1} − t_{n−1} within 2P ± ½P): a repeated, early or late stamp; re-stamped midway;
    * ``backward_stamp`` — the stamps step back and go on from there (a clock step back):
      the rest of the demonstration is shifted so that the interval is P;
    * ``clock_step`` — an interval beyond GAP_PERIODS·P + GAP_JITTER·J across which the
      positions moved as in one period (the time did not pass): shifted like a backward step;
    * ``gap`` — such an interval the positions do not contradict (lost samples, a pause, or a
      sensor at rest, where nobody can tell): reported with the number of missing periods.

    The per-sample work is on (N,) arrays; positions are compared only where a stamp repeats.
    """
    return _stamp_faults(t, X, demo)[:3]


def _stamp_faults(t: np.ndarray, X: np.ndarray, demo: np.ndarray
                  ) -> tuple[list[Finding], np.ndarray, np.ndarray, float]:
    """:func:`stamp_faults`, and the period P it measured (0 when no interval is positive)."""
    t = np.asarray(t, dtype=float)
    X = np.asarray(X, dtype=float)
    demo = np.asarray(demo)
    n = len(t)
    same = np.r_[False, demo[1:] == demo[:-1]]  # n has a predecessor in its demonstration
    dt = np.r_[0.0, np.diff(t)]
    period, jitter = _period(dt[same])
    repeated = np.flatnonzero(same & (dt == 0))
    keep = np.ones(n, dtype=bool)
    keep[repeated[(X[repeated] == X[repeated - 1]).all(1)]] = False
    findings = [Finding("duplicate_sample", ~keep, "dropped")]
    t_new = t.copy()
    if period <= 0:
        return findings, t_new, keep, period
    limit = GAP_PERIODS * period + GAP_JITTER * jitter
    odd = same & keep & ((dt <= 0) | (dt > limit))
    # a single bad stamp: its neighbours' stamps are two periods apart
    k = np.flatnonzero(odd)
    has_next = (k < n - 1) & (demo[np.minimum(k + 1, n - 1)] == demo[k])
    span = t[np.minimum(k + 1, n - 1)] - t[np.maximum(k - 1, 0)]
    k_bad = k[has_next & (np.abs(span - 2 * period) <= 0.5 * period)]
    bad = np.zeros(n, dtype=bool)
    bad[k_bad] = True
    t_new[k_bad] = 0.5 * (t[k_bad - 1] + t[np.minimum(k_bad + 1, n - 1)])
    after_bad = np.r_[False, bad[:-1]]  # the interval after a bad stamp is explained by it
    rest = odd & ~bad & ~after_bad
    back = rest & (dt <= 0)
    forward = rest & (dt > 0)
    step, missing = _clock_steps(t, X, demo, forward, period)
    restamp = back | step
    if restamp.any():
        t_new += _per_demo_cumsum(np.where(restamp, period - dt, 0.0), demo)
    gaps = forward & ~step
    findings += [Finding("bad_stamp", bad, "restamped"), Finding("backward_stamp", back, "restamped"),
                 Finding("clock_step", step, "restamped"),
                 Finding("gap", gaps, "reported", {"missing_periods": missing[~step[forward]].tolist()})]
    return [f for f in findings if f], t_new, keep, period


def repeated_poses(t: np.ndarray, X: np.ndarray, demo: np.ndarray, action: str = "dropped") -> Finding:
    """Samples that repeat the pose before them, in a recording whose sensor updates more slowly
    than it was logged: t (N,) s, X (N, d), demo (N,).

    Found when the repeats are frequent and the new poses steady (:data:`HELD_SHARE`,
    :data:`HELD_MIN_POSES`, :data:`HELD_STEADY`); P is the median interval between new poses.
    ``mask`` marks the samples to drop: every repeat, except that a pose held for m ≥ 2 periods
    (the sensor at rest, reporting the same pose at each update) keeps one sample per period —
    the first at or after each multiple of P — so a rest stays a rest, with its updates.
    ``detail``: ``rate_hz`` (1/P, the sensor's rate), ``log_rate_hz`` (the samples' median
    rate), ``per_pose`` (median samples per pose), ``poses`` (the new poses); ``count`` the
    samples concerned."""
    t = np.asarray(t, dtype=float)
    X = np.asarray(X, dtype=float)
    demo = np.asarray(demo)
    n = len(t)
    none = Finding("repeated_pose", np.zeros(n, dtype=bool), action, count=0)
    if n < 3:
        return none
    same = np.r_[False, demo[1:] == demo[:-1]]
    repeat = same.copy()
    repeat[1:] &= (X[1:] == X[:-1]).all(1)
    if not same.any() or repeat.sum() < HELD_SHARE * same.sum():
        return none
    new = np.flatnonzero(~repeat)  # the first sample of each pose (each demonstration's first too)
    follows = demo[new[1:]] == demo[new[:-1]]
    if len(new) < HELD_MIN_POSES or not follows.any():
        return none
    gaps = (t[new[1:]] - t[new[:-1]])[follows]
    period, spread = _period(gaps)
    log_period, _ = _period(np.diff(t)[same[1:]])
    if period <= 0 or spread > HELD_STEADY * period or period < 1.5 * log_period:
        return none  # no steady updates, or one at every sample (repeats only where it rests)
    # each pose's run: its start time, and how many periods it lasts (to the next pose, or to one
    # logging interval past its demonstration's last sample)
    run = np.cumsum(~repeat) - 1
    _, stop = _demo_bounds(demo)
    ends = np.r_[t[new[1:]], 0.0]
    last = np.r_[~follows, True]  # the last pose of its demonstration
    ends[last] = t[stop[new[last]] - 1] + log_period
    periods = np.rint((ends - t[new]) / period)
    phase = np.floor((t - t[new][run]) / period)
    earlier = np.r_[-1.0, phase[:-1]]
    kept = ~repeat | ((phase >= 1) & (phase <= periods[run] - 1) & (phase > earlier) & repeat)
    mask = ~kept
    detail = {"rate_hz": 1.0 / period, "log_rate_hz": 1.0 / log_period if log_period > 0 else None,
              "per_pose": float(np.median(np.diff(np.r_[new, n]))), "poses": int(len(new))}
    return Finding("repeated_pose", mask, action, detail, count=int(mask.sum()))


def _slope(t: np.ndarray, X: np.ndarray, idx: np.ndarray, valid: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Least-squares velocity of X over the samples idx (M, m) where valid (M, m): (M, d), and
    S = Σ(t − t̄)² (M,), so that white position noise σ gives the velocity noise σ/√S."""
    w = valid.astype(float)
    count = np.maximum(w.sum(1, keepdims=True), 1.0)
    tc = t[idx] - (w * t[idx]).sum(1, keepdims=True) / count
    Xc = X[idx] - np.einsum("mj,mjd->md", w, X[idx])[:, None, :] / count[..., None]
    S = (w * tc**2).sum(1)
    v = np.einsum("mj,mjd->md", w * tc, Xc) / np.maximum(S, 1e-300)[:, None]
    return v, S


def _clock_steps(t: np.ndarray, X: np.ndarray, demo: np.ndarray, at: np.ndarray, period: float
                 ) -> tuple[np.ndarray, np.ndarray]:
    """For the long intervals ending at samples ``at`` (N,) bool: which are clock steps (N,)
    bool (the positions moved across the interval as in one period — displacement within
    MOTION_Z noise plus half a period's motion of v·period — while the motion on either
    side, had the interval's time passed, would have moved them by > MOTION_Z × noise), and
    for each of ``at``'s samples in order (K,) the number of periods the positions say
    passed (rounded, ≥ 1) less one."""
    n = len(t)
    step = np.zeros(n, dtype=bool)
    k = np.flatnonzero(at)
    if not len(k):
        return step, np.zeros(0)
    starts = np.flatnonzero(np.r_[True, demo[1:] != demo[:-1]])
    piece = np.searchsorted(starts, k, side="right") - 1
    lo, hi = starts[piece], np.r_[starts[1:], n][piece]  # the demonstration of each k
    m = max(int(round(VELOCITY_SPAN_S / period)), 2)  # samples on each side
    before = k[:, None] - m + np.arange(m)  # k − m … k − 1
    after = k[:, None] + np.arange(m)  # k … k + m − 1
    ok_before = before >= lo[:, None]
    ok_after = after < hi[:, None]
    v_left, s_left = _slope(t, X, np.clip(before, 0, n - 1), ok_before)
    v_right, s_right = _slope(t, X, np.clip(after, 0, n - 1), ok_after)
    v = 0.5 * (v_left + v_right)
    speed = np.sqrt((v**2).sum(1))
    elapsed = np.einsum("md,md->m", X[k] - X[k - 1], v) / np.maximum(speed**2, 1e-300)
    # position noise, all axes (a noise-free recording: 10⁻¹² of its extent, whatever the unit)
    sigma = max(float(np.sqrt(white_noise_var(X, demo).sum())), 1e-12 * float(np.abs(X).max()),
                np.finfo(float).tiny)
    with np.errstate(divide="ignore"):
        sigma_v = 0.5 * sigma * np.sqrt(1 / s_left + 1 / s_right)
    dt = t[k] - t[k - 1]
    # the velocity is real and the two hypotheses, one period or dt, put the sample apart by
    # more than the noise of the displacement (√2 σ)
    moving = (speed > MOTION_Z * sigma_v) & (speed * (dt - period) > MOTION_Z * np.sqrt(2) * sigma)
    # and the displacement is the motion of one period (within the noise and half a period's
    # motion), not a jump elsewhere across a pause (a new stroke starting somewhere else)
    one_period = np.sqrt(((X[k] - X[k - 1] - v * period) ** 2).sum(1))
    fits = one_period <= MOTION_Z * np.sqrt(2) * sigma + 0.5 * speed * period
    step[k] = moving & fits & (np.abs(elapsed - period) < np.abs(elapsed - dt))
    missing = np.where(moving, np.maximum(np.round(elapsed / period), 1.0), np.round(dt / period)) - 1
    return step, missing


# -- force/torque ------------------------------------------------------------------------------
def force_bias(F: np.ndarray, t: np.ndarray, demo: np.ndarray, free: np.ndarray | None = None,
               edge_s: float = FREE_EDGE_S, z: float = BIAS_Z) -> Finding:
    """A constant offset in a force/torque channel F (N, c).

    Where the tool is free (``free`` (N,) bool, or by default the first and last ``edge_s`` s
    of every demonstration, when a recording starts and ends out of contact) a zeroed sensor
    reads zero plus noise. The bias is the median there, per channel; it is reported when it
    exceeds ``z`` standard errors (1.25 σ/√n, σ from the median absolute deviation there) and
    half of σ in some channel. Not removed: a reader cannot know what the sensor should read.
    ``detail``: value (c,), its standard error, the noise σ, and the start-minus-end
    difference of the medians (a drift, when it exceeds the standard errors).
    """
    F = np.asarray(F, dtype=float)
    t = np.asarray(t, dtype=float)
    if free is None:
        lo, hi = _demo_bounds(demo)
        free = (t - t[lo] <= edge_s) | (t[hi - 1] - t <= edge_s)
    free = np.asarray(free, dtype=bool)
    rest = F[free]
    if len(rest) < 3:
        return Finding("force_bias", np.zeros(len(F), bool), "reported", {}, count=0)
    value = np.median(rest, axis=0)
    sigma = robust_std(rest - value)
    se = 1.2533 * sigma / np.sqrt(len(rest))
    lo, _ = _demo_bounds(demo)
    early = free & (t - t[lo] <= edge_s)
    drift = np.median(F[early], 0) - np.median(F[free & ~early], 0) if (free & ~early).any() else value * 0
    found = bool(np.any((np.abs(value) > z * se) & (np.abs(value) > 0.5 * sigma)))
    detail = {"value": value.tolist(), "standard_error": se.tolist(), "noise_std": sigma.tolist(),
              "start_minus_end": np.asarray(drift).tolist()}
    return Finding("force_bias", np.zeros(len(F), bool), "reported", detail, count=int(found))


# -- all of it, as a reader calls it ------------------------------------------------------------
@dataclass
class Cleaned:
    """Positions after :func:`clean_positions`: t (M,), X (M, d), demo (M,) — the kept samples,
    repaired — ``keep`` (N,) which input samples they are, and the findings (masks over the
    N input samples)."""

    t: np.ndarray
    X: np.ndarray
    demo: np.ndarray
    keep: np.ndarray
    findings: list[Finding]

    def report(self, t: np.ndarray) -> list[dict[str, Any]]:
        """Every finding as a dict, ranges and times in the input's samples and stamps t (N,)."""
        return [f.as_dict(t) for f in self.findings]

    def record(self) -> Repair:
        """What was done to each input sample, and why (:func:`repair_record`)."""
        return repair_record(self.findings, self.keep)


#: The precedence of what was done to a sample several findings cover.
_PRECEDENCE = {"reported": 0, "restamped": 1, "mirrored": 2, "dropped": 3}


def repair_record(findings: list[Finding], keep: np.ndarray) -> Repair:
    """What the repair did to each of the N input samples (:class:`~ccl_cli.dataset.Repair`):
    ``dropped`` where ``keep`` (N,) is False, else ``mirrored`` or ``restamped`` where a finding
    with that action covers it, else ``kept``; the reason is the kind of the finding behind it (a
    kept sample a finding covers was found faulty and reported, kept as recorded). The row of a
    kept sample is its place among the kept ones."""
    n = len(keep)
    level, why = np.full(n, -1, np.int8), np.zeros(n, np.uint8)
    kinds = ("", *dict.fromkeys(f.kind for f in findings))
    for f in findings:  # a loop over the kinds of fault
        rank = _PRECEDENCE.get(f.action, 0)
        on = f.mask & (rank > level)
        level[on], why[on] = rank, kinds.index(f.kind)
    done = np.select([~keep, level == 2, level == 1], [3, 1, 2], 0).astype(np.uint8)
    return Repair(done, why, kinds, np.where(keep, np.cumsum(keep) - 1, -1).astype(np.int64))


def run_edges(mask: np.ndarray, reach: int) -> np.ndarray:
    """The samples within ``reach`` of a start or end of a run of True in ``mask`` (N,)."""
    change = np.flatnonzero(np.diff(mask.astype(np.int8)) != 0) + 1
    near = np.zeros(len(mask), dtype=bool)
    for offset in range(-reach, reach):  # a loop over offsets, not samples
        near[np.clip(change + offset, 0, len(mask) - 1)] = True
    return near


def _take(keep: np.ndarray, idx: np.ndarray | None, *arrays: np.ndarray
          ) -> tuple[np.ndarray | None, ...]:
    """The input indices (``idx`` None: all of them) and ``arrays`` of the samples ``keep``
    (a mask); nothing is copied when every sample is kept."""
    if keep.all():
        return (idx, *arrays)
    return (np.flatnonzero(keep) if idx is None else idx[keep], *(a[keep] for a in arrays))


def _widen(mask: np.ndarray, where: np.ndarray | None, n: int) -> np.ndarray:
    """A mask over ``n`` samples that is ``mask`` at the indices ``where`` (None: all)."""
    if where is None:
        return mask.copy()
    out = np.zeros(n, dtype=bool)
    out[where[mask]] = True
    return out


def clean_positions(t: np.ndarray, X: np.ndarray, demo: np.ndarray, flips: str = "mirror",
                    drop_spikes: bool = True, stamps: bool = True) -> Cleaned:
    """Repeated poses (:func:`repeated_poses`: dropped with ``stamps``, else reported), stamp
    faults (:func:`stamp_faults`), then hemisphere flips (``flips``: ``mirror`` them
    back, ``drop`` them, or ``keep`` them as they are), then spikes (dropped unless
    ``drop_spikes`` is False) on t (N,), X (N, d), demo (N,). Findings that were kept are
    reported with action ``reported``. Arrays no check changed are returned as given."""
    if flips not in FLIP_ACTIONS:
        raise ConfigError(f"flips must be one of {', '.join(FLIP_ACTIONS)}, got {flips!r}")
    t, X, demo = np.asarray(t, float), np.asarray(X, float), np.asarray(demo)
    n = len(t)
    idx: np.ndarray | None = None  # the input index of every sample still in (None: all)
    findings: list[Finding] = []
    period = None  # the stamps' period, when spikes sees the same intervals (else measured there)
    held = repeated_poses(t, X, demo, "dropped" if stamps else "reported")
    if held:
        findings.append(held)
        if stamps:  # the stamp checks then see the sensor's own period
            idx, t, X, demo = _take(~held.mask, idx, t, X, demo)
    if stamps:
        found, t, keep, measured = _stamp_faults(t, X, demo)
        findings += [f if idx is None else
                     Finding(f.kind, _widen(f.mask, idx, n), f.action, f.detail, f.count) for f in found]
        idx, X, demo, t = _take(keep, idx, X, demo, t)
        if not found and not held and bool((demo[1:] == demo[:-1]).all()):
            period = measured  # the stamps unchanged, no demonstration edge: the same median
    flip = hemisphere_flips(X, demo)
    if flip:
        if flips == "mirror":
            X = unflip(X, flip)
        flip.action = FLIP_ACTIONS[flips]
        findings.append(Finding(flip.kind, _widen(flip.mask, idx, n), flip.action, flip.detail))
        if flips == "drop":
            idx, t, X, demo = _take(~flip.mask, idx, t, X, demo)
            period = None
    spike = spikes(X, t, demo, period=period)
    if flip and flips == "keep":  # the jumps of flips left in place are no spikes
        edges = run_edges(flip.mask, 3)
        spike = Finding(spike.kind, spike.mask & ~edges, spike.action, spike.detail)
    if spike:
        spike.action = "dropped" if drop_spikes else "reported"
        findings.append(Finding(spike.kind, _widen(spike.mask, idx, n), spike.action, spike.detail))
        if drop_spikes:
            idx, t, X, demo = _take(~spike.mask, idx, t, X, demo)
    keep = np.ones(n, dtype=bool) if idx is None else _widen(np.ones(len(idx), bool), idx, n)
    return Cleaned(t=t, X=X, demo=demo, keep=keep, findings=findings)
