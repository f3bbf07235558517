"""Realistic recordings with their faults, and ground truth (issue 17).

The reference problems are right for the learners they were tuned on; real recordings
also carry sensor faults, constraints that change over time, free phases and motions with
no constraint at all. Each function here is seeded and returns
:class:`~ccl_cli.dataset.Demonstrations` with ``truth`` and a ``metadata`` dict describing
the scenario and every injected fault, so tests can check detection against it:

* :func:`tracker_flips` — :func:`~ccl_cli.simulate.tracker.tracker_plane` /
  :func:`~ccl_cli.simulate.tracker.tracker_sphere` with the faults of a magnetic tracker:
  hemisphere flips, optional isolated spikes and stamp faults.
* :func:`tracker_tilt` — a finger on a plane whose normal tilts over time.
* :func:`free_reach` — 3-D point-to-point reaches in free space (no constraint).
* :func:`flow2d` — 2-D handwriting-like strokes converging on a goal (no constraint).

The 7-DoF arm wiping a plane lives in :mod:`ccl_cli.simulate.wipe`.

``metadata["faults"]`` is a list of ``{"kind", "count", "ranges", "times", ...}``: ``ranges``
are ``[start, stop)`` sample indices of the returned arrays, ``times`` the stamps of the first
and last sample of each range.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, Derivative
from ccl_cli.errors import ConfigError
from ccl_cli.io.derivative import local_polynomial_derivative, window_for_rate
from ccl_cli.learn.linalg import nullspace_projection, unit_rows
from ccl_cli.simulate.tracker import (
    _tilt,
    _tracker_path,
    _tracker_segments,
    tracker_plane,
    tracker_sphere,
)

#: Stamp faults :func:`tracker_flips` can inject (see its docstring) and the kind each is
#: listed as in ``metadata["faults"]`` (the kinds :mod:`ccl_cli.io.faults` reports).
STAMP_FAULTS = {"repeat": "bad_stamp", "duplicate": "duplicate_sample", "skip": "gap", "step": "clock_step",
                "back": "backward_stamp"}
#: Where the tracker simulations put the surface in the transmitter's frame (m).
TRACKER_ORIGIN = np.array([0.30, -0.05, 0.12])


# -- shared pieces -----------------------------------------------------------------------
def derive(t: np.ndarray, X: np.ndarray, demo: np.ndarray, rate: float, order: int = 2
           ) -> tuple[np.ndarray, dict[str, int]]:
    """Velocities the readers would derive from positions X (N, d) at stamps t (N,): the
    local polynomial of degree ``order`` over the default window for ``rate`` Hz. Returns
    (U (N, d), {"window", "order"})."""
    window = window_for_rate(rate, order)
    return local_polynomial_derivative(t, X, demo, window, order), {"window": window, "order": order}


def stroke_phase(tau: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Minimum-jerk phase σ(τ) = 10τ³ − 15τ⁴ + 6τ⁵ and dσ/dτ for τ (any shape) clipped to [0, 1]:
    a point-to-point movement that starts and ends at rest."""
    tau = np.clip(tau, 0.0, 1.0)
    return tau**3 * (10 - 15 * tau + 6 * tau**2), 30 * tau**2 * (1 - tau) ** 2


def fault(kind: str, ranges: list[tuple[int, int]], t: np.ndarray, **extra: Any) -> dict[str, Any]:
    """One entry of ``metadata["faults"]``: ``kind``, ``count``, ``n_samples``, ``ranges``
    ([start, stop) sample indices, sorted) and ``times`` (stamps of their first and last samples)."""
    ranges = sorted((int(a), int(b)) for a, b in ranges)
    return {"kind": kind, "count": len(ranges), "n_samples": int(sum(b - a for a, b in ranges)),
            "ranges": [list(r) for r in ranges],
            "times": [[float(t[a]), float(t[b - 1])] for a, b in ranges], **extra}


def position_recording(X: np.ndarray, U: np.ndarray, demo: np.ndarray, t: np.ndarray,
                       truth: dict[str, np.ndarray], metadata: dict[str, Any], derived: dict[str, int]
                       ) -> Demonstrations:
    """Demonstrations of positions X (N, d) in m (axes x, y[, z]) and their velocities U (N, d),
    derived by the local polynomial ``derived`` ({"window", "order"}, :func:`derive`)."""
    axes = ["x", "y", "z"][: X.shape[1]]
    return Demonstrations(X=X, U=U, demo=demo, t=t, truth=truth, state_names=axes,
                          action_names=[f"d{a}/dt" for a in axes], state_units=["m"] * len(axes),
                          action_units=["m/s"] * len(axes), metadata=metadata,
                          derivative=Derivative.of(derived))


def _free_truth(V: np.ndarray) -> dict[str, np.ndarray]:
    """Ground truth of unconstrained motion with true velocity V (N, q): N = I, π = w = V, v = 0."""
    return {"N": np.eye(V.shape[1]), "pi": V, "w": V.copy(), "v": np.zeros_like(V)}


def _pick_sites(rng: np.random.Generator, starts: np.ndarray, stops: np.ndarray,
                lengths: list[int], margin: int) -> list[int]:
    """Start indices of non-overlapping stretches of the given ``lengths`` (samples), each
    inside one demonstration [starts[d], stops[d]) and ``margin`` samples away from its ends
    and from every other stretch (rejection sampling; a loop over the stretches)."""
    taken: list[tuple[int, int]] = []
    sizes = stops - starts
    out = []
    for length in lengths:
        for _ in range(1000):
            d = int(rng.choice(len(starts), p=sizes / sizes.sum()))
            lo, hi = starts[d] + margin, stops[d] - margin - length
            if hi <= lo:
                continue
            s = int(rng.integers(lo, hi))
            if all(s + length + margin <= a or s >= b + margin for a, b in taken):
                taken.append((s, s + length))
                out.append(s)
                break
        else:
            raise ConfigError("too many faults for this recording: make it longer or inject fewer")
    return out


# -- a magnetic tracker's faults -------------------------------------------------------------
def tracker_flips(
    surface: str = "plane",
    n_flips: int = 3,
    flip_s: tuple[float, float] = (0.3, 0.4),
    n_spikes: int = 0,
    spike_m: tuple[float, float] = (0.02, 0.08),
    stamp_faults: tuple[str, ...] = (),
    offset: tuple[float, float, float] = (0.0, 0.0, 0.0),
    duration: float = 90.0,
    rate: float = 50.0,
    noise: float = 1e-3,
    n_recordings: int = 1,
    seed: int = 0,
) -> Demonstrations:
    """A Trakstar-style recording of a finger on a plane (``surface="plane"``) or in a bowl
    (``"sphere"``) — :func:`~ccl_cli.simulate.tracker.tracker_plane` /
    :func:`~ccl_cli.simulate.tracker.tracker_sphere` with the same ``duration``, ``rate``,
    ``noise``, ``n_recordings`` and ``seed`` — with the faults of a magnetic tracker injected
    into the positions before the velocities are derived (as a reader would derive them):

    * ``n_flips`` hemisphere flips: for a stretch of ``flip_s`` s (uniform) the sensor reports
      its position mirrored through the transmitter, (x, y, z) → (−x, −y, −z), with a jump of
      2‖x‖ at each end (the surface sits ~0.33 m from the transmitter: 0.66-m jumps, velocity
      spikes of several m/s in the derived actions);
    * ``n_spikes`` isolated spikes: one sample displaced by ``spike_m`` m (uniform) in a random
      direction;
    * ``stamp_faults``, each entry one fault: ``repeat`` (a sample carries the stamp of the one
      before it), ``duplicate`` (a sample recorded twice: same stamp and position), ``skip``
      (a sample lost: one period missing), ``step`` (the clock steps forward 0.2–1 s while the
      motion goes on), ``back`` (the clock steps back 2–5 periods: stamps not monotonic);
      listed in the metadata under the kinds of :data:`STAMP_FAULTS`.

    ``offset`` (m) moves the transmitter: positions are reported relative to it
    (−``TRACKER_ORIGIN`` puts the drawing around the transmitter, where a flip moves a sample
    little). Faults are at least one derivative window apart and away from the ends of a
    recording; their random draws have a stream of their own, so the clean recording is the
    one the tracker function returns for ``seed``.

    Returns X (N, 3) faulty positions (m), U (N, 3) velocities derived from them (m/s), t (N,)
    faulty stamps (s); truth as the clean recording's (the surface normal, π of the true
    path); ``metadata["faults"]`` (see the module docstring; a flip's entry also gives
    ``peak_speed``, the largest derived speed within a window of its ends, m/s).
    """
    makers = {"plane": tracker_plane, "sphere": tracker_sphere}
    if surface not in makers:
        raise ConfigError(f"unknown tracker surface {surface!r} (use plane or sphere)")
    bad = [k for k in stamp_faults if k not in STAMP_FAULTS]
    if bad:
        raise ConfigError(f"unknown stamp fault {bad[0]!r} (use {', '.join(STAMP_FAULTS)})")
    if min(n_flips, n_spikes) < 0 or not 0 < flip_s[0] <= flip_s[1] or not 0 < spike_m[0] <= spike_m[1]:
        raise ConfigError("tracker_flips needs n_flips, n_spikes ≥ 0 and positive flip_s, spike_m ranges")
    clean = makers[surface](duration=duration, rate=rate, noise=noise, n_recordings=n_recordings, seed=seed)
    rng = np.random.default_rng([seed, 0xF11B])
    window = clean.derivative.window
    n = clean.n_samples
    starts = np.flatnonzero(np.r_[True, clean.demo[1:] != clean.demo[:-1]])
    stops = np.r_[starts[1:], n]
    flip_len = [int(round(rng.uniform(*flip_s) * rate)) for _ in range(n_flips)]
    sites = _pick_sites(rng, starts, stops, [*flip_len, *[1] * (n_spikes + len(stamp_faults))], 2 * window)
    flip_at, spike_at = sites[:n_flips], sites[n_flips:n_flips + n_spikes]
    stamp_at = dict(zip(sites[n_flips + n_spikes:], stamp_faults, strict=True))

    # rows: a lost sample disappears, a duplicated one appears twice
    skips = [i for i, k in stamp_at.items() if k == "skip"]
    dups = [i for i, k in stamp_at.items() if k == "duplicate"]
    src = np.sort(np.r_[np.delete(np.arange(n), skips), dups].astype(int), kind="stable")
    new = np.searchsorted(src, np.arange(n + 1))  # new index of each original sample (first copy)
    data = clean.subset(src)
    X, t, demo = data.X + np.asarray(offset, float), data.t.copy(), data.demo
    period = 1.0 / rate
    faults = []
    stamp_ranges: dict[str, list[tuple[int, int]]] = {}
    for i, kind in sorted(stamp_at.items()):
        j = int(new[i]) + (1 if kind == "duplicate" else 0)
        end = int(new[stops[np.searchsorted(starts, i, side="right") - 1]])  # end of its recording
        if kind == "repeat":
            t[j] = t[j - 1]
        elif kind == "step":
            t[j:end] += rng.uniform(0.2, 1.0)
        elif kind == "back":
            t[j:end] -= rng.uniform(2.0, 5.0) * period
        stamp_ranges.setdefault(kind, []).append((j, j + 1))
    flips = [(int(new[s]), int(new[s + L])) for s, L in zip(flip_at, flip_len, strict=True)]
    for a, b in flips:
        X[a:b] *= -1.0
    spikes = [(int(new[s]), int(new[s]) + 1) for s in spike_at]
    if spikes:
        idx = np.array([a for a, _ in spikes])
        X[idx] += unit_rows(rng.normal(size=(len(idx), 3))) * rng.uniform(*spike_m, (len(idx), 1))
    U, deriv = derive(t, X, demo, rate)
    speed = np.linalg.norm(U, axis=1)
    if flips:
        near = [speed[max(a - window, 0):b + window].max() for a, b in flips]
        faults.append(fault("hemisphere_flip", flips, t, peak_speed=[float(v) for v in near]))
    if spikes:
        faults.append(fault("spike", spikes, t))
    faults += [fault(STAMP_FAULTS[k], r, t) for k, r in stamp_ranges.items()]
    meta = {**clean.metadata, "simulated": "tracker_flips", "surface": surface, "derivative": deriv,
            "offset_m": [float(v) for v in offset], "faults": faults}
    return position_recording(X, U, demo, t, data.truth, meta, deriv)


# -- a surface that tilts -------------------------------------------------------------------
def rotation(r: np.ndarray) -> np.ndarray:
    """Rotation matrices (N, 3, 3) of rotation vectors r (N, 3) (axis · angle, Rodrigues)."""
    theta = np.linalg.norm(r, axis=1)
    k = r / np.maximum(theta, 1e-300)[:, None]
    K = np.zeros((len(r), 3, 3))
    K[:, 0, 1], K[:, 0, 2], K[:, 1, 2] = -k[:, 2], k[:, 1], -k[:, 0]
    K = K - K.transpose(0, 2, 1)
    s, c = np.sin(theta)[:, None, None], np.cos(theta)[:, None, None]
    return np.eye(3) + s * K + (1 - c) * K @ K


def _blend(t: np.ndarray, values: np.ndarray, centres: np.ndarray, span: float) -> np.ndarray:
    """values[0] + Σ_k (values[k+1] − values[k]) h((t − centres[k]) / span): a raised-cosine
    step h from 0 to 1 over [−½, ½] between consecutive values (K, d) at each of the K − 1
    ``centres`` (s). t (N,) → (N, d)."""
    s = np.clip((t[:, None] - centres[None, :]) / span + 0.5, 0.0, 1.0)
    h = 0.5 * (1.0 - np.cos(np.pi * s))
    return values[0] + h @ np.diff(values, axis=0)


def tracker_tilt(
    mode: str = "smooth",
    window_s: float = 6.0,
    tilt_deg: tuple[float, float] = (2.0, 14.0),
    base_tilt_deg: float = 20.0,
    duration: float = 60.0,
    rate: float = 50.0,
    noise: float = 1e-3,
    extent: float = 0.08,
    speed: tuple[float, float] = (0.03, 0.12),
    pause: tuple[float, float] = (0.5, 3.0),
    seed: int = 0,
) -> Demonstrations:
    """One continuous tracker recording (as :func:`~ccl_cli.simulate.tracker.tracker_plane`: a
    finger tracing strokes, positions with white noise of std ``noise`` m, velocities derived
    as the readers do) on a board whose normal changes over time.

    The board is first tilted by ``base_tilt_deg`` about a seeded horizontal axis; in each
    ``window_s``-s window k it is tilted further by φ_k ~ U(``tilt_deg``) about a random axis in
    its own plane (rotation vector τ_k), so the normals of two windows are 0–2·max(``tilt_deg``)
    apart. ``mode="smooth"``: τ(t) moves between the windows' values by raised-cosine blends
    spanning a whole window (the board turns all the time); ``"steps"``: τ is constant within a
    window and changes in 0.5 s at its boundary. The board turns about the middle of the
    drawing, x(t) = c + R(t)(a, b, 0) with R(t) = R_base · Rot(τ(t)).

    Truth per sample: A = n(t)ᵀ (N, 1, 3), N = I − nnᵀ; the true velocity ẋ (the derivative of
    the noise-free path, which includes the board's own turning) split as b = nᵀẋ (N, 1),
    v = n b, w = π = ẋ − v. ``metadata["windows"]``: each window's [t0, t1], mean normal and
    its angle to every other window (``angle_range_deg``: the smallest and largest of them).
    """
    if mode not in ("smooth", "steps"):
        raise ConfigError(f"unknown tilt mode {mode!r} (use smooth or steps)")
    if not (window_s > 0 and duration >= 2 * window_s and 0 <= tilt_deg[0] <= tilt_deg[1] < 45):
        raise ConfigError("tracker_tilt needs window_s > 0, duration ≥ 2 windows and tilt_deg in [0°, 45°)")
    rng = np.random.default_rng(seed)
    base = _tilt(rng, base_tilt_deg)
    n_win = int(np.ceil(duration / window_s - 1e-9))
    phi = np.deg2rad(rng.uniform(*tilt_deg, n_win))
    psi = rng.uniform(0.0, 2 * np.pi, n_win)
    tau = np.stack([phi * np.cos(psi), phi * np.sin(psi), np.zeros(n_win)], 1)
    seg = _tracker_segments(rng, duration, extent, speed, pause, (0.5, 1.0))
    edges = window_s * np.arange(1, n_win)
    span = window_s if mode == "smooth" else 0.5

    def pose(ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        R = base @ rotation(_blend(ts, tau, edges, span))
        ab, _ = _tracker_path(seg, ts)
        return TRACKER_ORIGIN + np.einsum("nij,nj->ni", R[:, :, :2], ab), R[:, :, 2]

    n = int(round(duration * rate))
    t = np.arange(n) / rate
    x_true, normal = pose(t)
    h = 1e-6  # the true velocity: central difference of the analytic path (error ~h²)
    xdot = (pose(t + h)[0] - pose(t - h)[0]) / (2 * h)
    X = x_true + rng.normal(scale=noise, size=x_true.shape) if noise else x_true.copy()
    demo = np.zeros(n, dtype=np.int64)
    U, deriv = derive(t, X, demo, rate)
    b = np.einsum("ni,ni->n", normal, xdot)[:, None]
    v = normal * b
    A = normal[:, None, :]
    truth = {"A": A, "N": nullspace_projection(A), "b": b, "v": v, "w": xdot - v, "pi": xdot - v}
    win = np.minimum((t // window_s).astype(int), n_win - 1)
    means = unit_rows(np.stack([normal[win == k].mean(0) for k in range(n_win)]))
    angles = np.degrees(np.arccos(np.clip(means @ means.T, -1.0, 1.0)))
    upper = angles[np.triu_indices(n_win, 1)]
    windows = [{"t": [float(k * window_s), float(min((k + 1) * window_s, duration))],
                "normal": means[k].tolist()} for k in range(n_win)]
    meta = {"simulated": "tracker_tilt", "mode": mode, "rate_hz": rate, "noise_m": noise,
            "derivative": deriv, "window_s": window_s, "windows": windows,
            "angles_deg": angles.round(3).tolist(),
            "angle_range_deg": [float(upper.min()), float(upper.max())], "faults": []}
    return position_recording(X, U, demo, t, truth, meta, deriv)


# -- motion with no constraint ------------------------------------------------------------------
def _sampled(durations: np.ndarray, rate: float) -> tuple[np.ndarray, np.ndarray]:
    """Stamps t (N,) from 0 within each demonstration of ``durations`` (D,) s at ``rate`` Hz,
    and the demonstration index of each sample."""
    counts = np.maximum(np.round(durations * rate).astype(int), 2)
    demo = np.repeat(np.arange(len(counts)), counts)
    first = np.repeat(np.cumsum(counts) - counts, counts)
    return (np.arange(counts.sum()) - first) / rate, demo


def _noisy(rng: np.random.Generator, Y: np.ndarray, std: float) -> np.ndarray:
    return Y + rng.normal(scale=std, size=Y.shape) if std else Y.copy()


def free_reach(
    n_demos: int = 6,
    n_reaches: int = 4,
    rate: float = 100.0,
    noise: float = 2e-4,
    box: tuple[float, float, float] = (0.5, 0.4, 0.15),
    centre: tuple[float, float, float] = (0.5, 0.0, 0.3),
    reach_s: tuple[float, float] = (0.8, 1.6),
    hold_s: tuple[float, float] = (0.2, 0.6),
    curvature: float = 0.15,
    seed: int = 0,
) -> Demonstrations:
    """End-effector reaches in free space: no constraint (A has no rows, N = I).

    Each of ``n_demos`` recordings holds still for a first ``hold_s`` s, then makes
    ``n_reaches`` point-to-point reaches between targets uniform in a ``box`` (m, extent per
    axis; flat by default, as over a table) around ``centre`` (m, in a robot's base frame),
    each lasting ``reach_s`` s with a minimum-jerk profile (:func:`stroke_phase`) along a path
    bowed sideways by sin(πσ)·h, h up to ``curvature`` × the reach's length in a random
    direction across it, and holding ``hold_s`` s at each target.

    Observed: X (N, 3) positions with white noise of std ``noise`` m at ``rate`` Hz; U (N, 3)
    velocities derived as the readers do. Truth: N = I (3, 3), π = w = the noise-free velocity,
    v = 0 (no A: its row count is zero).
    """
    if n_demos < 1 or n_reaches < 1 or not 0 < reach_s[0] <= reach_s[1] or hold_s[0] < 0:
        raise ConfigError("free_reach needs n_demos, n_reaches ≥ 1, reach_s > 0 and hold_s ≥ 0")
    rng = np.random.default_rng(seed)
    box_a, centre_a = np.asarray(box, float), np.asarray(centre, float)
    targets = centre_a + (rng.uniform(-0.5, 0.5, (n_demos, n_reaches + 1, 3)) * box_a)
    reach = rng.uniform(*reach_s, (n_demos, n_reaches))
    hold = rng.uniform(*hold_s, (n_demos, n_reaches + 1))
    d = np.diff(targets, axis=1)  # (D, R, 3)
    side = rng.normal(size=d.shape)
    side -= d * (np.einsum("drk,drk->dr", side, d) / np.maximum((d**2).sum(-1), 1e-300))[..., None]
    bow = unit_rows(side) * (rng.uniform(0, curvature, d.shape[:2]) * np.linalg.norm(d, axis=-1))[..., None]
    # per demonstration: hold, reach, hold, reach, ... (segment r starts at begin[:, r])
    seg_dur = np.zeros((n_demos, 2 * n_reaches + 1))
    seg_dur[:, 0::2], seg_dur[:, 1::2] = hold, reach
    begin = np.cumsum(seg_dur, axis=1) - seg_dur
    total = seg_dur.sum(1)
    t, demo = _sampled(total, rate)
    offset = np.cumsum(total) - total  # demonstrations laid end to end: one sorted table
    seg = np.searchsorted((begin + offset[:, None]).ravel(), t + offset[demo], side="right") - 1
    seg = np.clip(seg - demo * seg_dur.shape[1], 0, seg_dur.shape[1] - 1)
    r = np.maximum(seg - 1, 0) // 2  # the reach a segment belongs to (holds: the one before)
    moving = seg % 2 == 1
    tau = (t - begin[demo, seg]) / seg_dur[demo, seg]
    sigma, dsigma = stroke_phase(np.where(moving, tau, 1.0))
    sigma = np.where(moving | (seg > 0), sigma, 0.0)  # the first hold sits at the first target
    a, step, h = targets[demo, r], d[demo, r], bow[demo, r]
    x_true = a + sigma[:, None] * step + np.sin(np.pi * sigma)[:, None] * h
    rate_s = np.where(moving, dsigma / seg_dur[demo, seg], 0.0)[:, None]
    xdot = rate_s * (step + np.pi * np.cos(np.pi * sigma)[:, None] * h)
    X = _noisy(rng, x_true, noise)
    U, deriv = derive(t, X, demo, rate)
    meta = {"simulated": "free_reach", "rate_hz": rate, "noise_m": noise, "derivative": deriv,
            "n_constraints": 0, "faults": []}
    return position_recording(X, U, demo, t, _free_truth(xdot), meta, deriv)


def flow2d(
    n_demos: int = 7,
    rate: float = 100.0,
    noise: float = 1e-4,
    scale: float = 0.1,
    duration_s: tuple[float, float] = (3.0, 5.0),
    hold_s: float = 0.3,
    n_terms: int = 4,
    seed: int = 0,
) -> Demonstrations:
    """2-D handwriting-like strokes converging on a goal at the origin (a pen on a tablet,
    the shape of the LASA handwriting motions): no constraint (N = I).

    One seeded letter shape, p(σ) = (1 − σ) s + Σ_{k ≤ n_terms} c_k sin(kπσ) for σ ∈ [0, 1],
    with start s at distance ~``scale`` m from the goal and c_k ~ N(0, (scale/2k)²); each of
    the ``n_demos`` demonstrations writes it with its own start (s + N(0, (scale/10)²)) and
    coefficients (each × (1 + N(0, 0.15²))) in ``duration_s`` s with a minimum-jerk phase
    σ(t), then rests ``hold_s`` s on the goal. Every path ends at the origin, so real motion
    passes through the transmitter-like zero of the coordinates.

    Observed: X (N, 2) positions (m) with white noise of std ``noise`` at ``rate`` Hz; U (N, 2)
    velocities derived as the readers do. Truth: N = I (2, 2), π = w = the noise-free
    velocity, v = 0.
    """
    if n_demos < 1 or n_terms < 1 or not 0 < duration_s[0] <= duration_s[1] or hold_s < 0:
        raise ConfigError("flow2d needs n_demos, n_terms ≥ 1, duration_s > 0 and hold_s ≥ 0")
    rng = np.random.default_rng(seed)
    k = np.arange(1, n_terms + 1)
    ang = rng.uniform(0, 2 * np.pi)
    start = scale * rng.uniform(0.8, 1.2) * np.array([np.cos(ang), np.sin(ang)])
    coef = rng.normal(size=(n_terms, 2)) * (scale / (2 * k))[:, None]
    starts = start + rng.normal(scale=scale / 10, size=(n_demos, 2))
    coefs = coef * (1 + 0.15 * rng.normal(size=(n_demos, n_terms, 1)))
    move = rng.uniform(*duration_s, n_demos)
    t, demo = _sampled(move + hold_s, rate)
    sigma, dsigma = stroke_phase(t / move[demo])
    arg = np.pi * k[None, :] * sigma[:, None]  # (N, K)
    x_true = (1 - sigma)[:, None] * starts[demo] + np.einsum("nk,nkd->nd", np.sin(arg), coefs[demo])
    dp = -starts[demo] + np.einsum("nk,nkd->nd", np.pi * k * np.cos(arg), coefs[demo])
    xdot = dp * (dsigma / move[demo])[:, None]
    X = _noisy(rng, x_true, noise)
    U, deriv = derive(t, X, demo, rate)
    meta = {"simulated": "flow2d", "rate_hz": rate, "noise_m": noise, "derivative": deriv,
            "n_constraints": 0, "faults": []}
    return position_recording(X, U, demo, t, _free_truth(xdot), meta, deriv)
