"""Contact from a force channel: where a constraint holds and its row (DESIGN.md "Evidence for a
constraint", forces).

A tool pressed on a surface feels the surface push back along its normal while it moves (nearly)
not at all along that normal; a tool in free air feels no sustained force, and a tool pushed by a
hand moves along the push. "A reaction along the rows and no motion along them is contact": with
f the force in the base frame and u the velocity (N, 3), on windows of WINDOW_S s centred on each
sample (sliding means within each demonstration):

*Baseline and level.* A channel that is not zeroed reads an offset, which drifts. A recording starts
and ends out of contact (as :func:`ccl_cli.io.faults.force_bias` takes it): the baseline of a
demonstration is read at each end — its first and last EDGE_SHARE of the samples, on the windows
that move less than the median there (a hand that pushes moves the tool) and, of those, whose force
varies less than the median — and the mean of the two is its baseline b (a drift between them,
1–3 N on the KUKA rim log, stays below the level); the channel's noise σ is the median RMS
deviation within those windows. The force is *on* where |f̄ − b| > level = max(NOISE_K σ,
LEVEL_SHARE · P90), P90 the 90th percentile of |f̄ − b| over the recording: both terms scale with
the channel, so newtons and kilonewtons give the same samples.

*Reaction.* With C the window's second moment of u (3, 3), the window reacts when some direction
n within REACTION_DEG of the force f̄ − b carries at most MOTION_SHARE of its motion,
nᵀCn / tr C ≤ MOTION_SHARE — n the quietest of: the smallest eigenvector of C, the direction of
its two smallest nearest the force, the force's own (friction and a hand's tilt turn the force
away from the normal by 10–35°; the velocities pin the normal down). A window moves when
tr C > STILL_SHARE × the recording's median.

*Stretches.* Cores are the samples where the force is on, the window moves and reacts, with gaps
shorter than GAP_S filled and cores shorter than MIN_S dropped. Each core's row is the quietest
direction near its mean force of Σ u uᵀ over the core (ALGORITHMS.md §3.1 on it). A core then
grows over the samples around it where the force is on and the motion along its row stays within
GROW_SHARE of the window's (the touch-down and lift-off, where the force still pushes but the
window's motion is less clean); stretches that meet are joined. A stretch's row is the smallest
eigenvector of Σ u uᵀ over it, cross-checked: within REACTION_DEG of its mean force (else the
core's row is kept, and said).

*Held channels.* A sensor that stops updating repeats its value: runs of at least HELD_RUN
samples whose |f| repeats exactly carry no evidence (|R f| = |f|, so a held tool-frame value
rotated into the base frame is found too); a demonstration whose force is held throughout shows
no contact (said in :attr:`Contact.held`).

The thresholds were set on the KUKA rim-wiping recording and the simulated wipes (docs/auto.md).
Shapes: force (N, 3), U (N, 3), groups (N,), t (N,) s.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.errors import InputError

#: Window (s) of the sliding means.
WINDOW_S = 0.3
#: The baseline is read at the ends of each demonstration — its first and last EDGE_SHARE of the
#: samples, where a recording is out of contact — on the quarter of their windows that move less than
#: the median and, of those, vary less than the median.
EDGE_SHARE = 0.1
#: The force is on above NOISE_K × its noise and LEVEL_SHARE × its 90th percentile above baseline.
NOISE_K = 5.0
LEVEL_SHARE = 0.1
#: A window reacts when a direction within REACTION_DEG of the force carries at most MOTION_SHARE
#: of its motion (RMS speed along it ≤ 22 % of the RMS speed).
REACTION_DEG = 35.0
MOTION_SHARE = 0.05
#: A stretch grows over windows whose motion along its row is at most GROW_SHARE of theirs.
GROW_SHARE = 0.3
#: A stretch's row — the velocities' smallest direction over it — must lie within AGREE_DEG of its
#: mean force (the cross-check); else the quietest direction within REACTION_DEG of the force, when
#: it carries at most GROW_SHARE of the stretch's motion; else the stretch is no contact.
AGREE_DEG = 45.0
#: A window moves when tr C exceeds STILL_SHARE × the recording's median.
STILL_SHARE = 1e-2
#: Gaps shorter than GAP_S (s) inside a stretch are filled; stretches shorter than MIN_S (s) dropped.
GAP_S = 0.3
MIN_S = 1.0
#: A run of at least HELD_RUN samples repeating |f| exactly is a held channel.
HELD_RUN = 5
HELD_RTOL = 1e-12


@dataclass
class Stretch:
    """One contact stretch: demonstration ``demo``, rows [``start``, ``stop``) of the data, its
    row (3,) and mean force above baseline (3,), the angle between them (degrees), the share of
    its motion along the row, and how the row was read."""

    demo: int
    start: int
    stop: int
    row: np.ndarray
    force: np.ndarray
    angle_deg: float
    motion_share: float
    how: str = "the velocities' smallest direction, within the cone of the force"

    def as_dict(self, t: np.ndarray) -> dict[str, Any]:
        return {"demo": self.demo, "start_s": float(t[self.start]), "end_s": float(t[self.stop - 1]),
                "samples": self.stop - self.start, "row": [float(v) for v in self.row],
                "force_above_baseline": [float(v) for v in self.force], "angle_to_force_deg": self.angle_deg,
                "motion_share": self.motion_share, "row_from": self.how}


@dataclass
class Contact:
    """What the forces show: ``mask`` (N,) contact, the ``stretches``, per demonstration its
    baseline (3,), the share of its samples whose channel is held, and the level (one, in the
    channel's unit) and noise σ."""

    mask: np.ndarray
    stretches: list[Stretch]
    baseline: dict[int, np.ndarray] = field(default_factory=dict)
    held: dict[int, float] = field(default_factory=dict)
    level: float = 0.0
    noise: float = 0.0

    def rows(self) -> np.ndarray:
        """The row at each sample (N, 1, 3): its stretch's, zeros outside contact."""
        out = np.zeros((len(self.mask), 1, 3))
        for s in self.stretches:
            out[s.start:s.stop, 0] = s.row
        return out

    def summary(self, t: np.ndarray, groups: np.ndarray) -> dict[str, Any]:
        """JSON: the share of contact overall and per demonstration, the level and noise, the
        stretches, the held share per demonstration."""
        ids = np.unique(groups)
        return {"contact_share": float(self.mask.mean()) if len(self.mask) else 0.0,
                "per_demo": {str(int(d)): float(self.mask[groups == d].mean()) for d in ids},
                "level": self.level, "noise": self.noise,
                "baseline": {str(d): [float(v) for v in b] for d, b in self.baseline.items()},
                "held_share": {str(d): v for d, v in self.held.items()},
                "stretches": [s.as_dict(t) for s in self.stretches]}


def held(force: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """(N,) bool: samples in runs of at least HELD_RUN within a demonstration whose |f| repeats
    (to HELD_RTOL of the channel's largest: the rounding of a rotation) — a channel that stopped
    updating."""
    n = len(force)
    mag = np.linalg.norm(force, axis=1)
    tol = HELD_RTOL * float(mag.max(initial=0.0))
    same = np.r_[False, (np.abs(np.diff(mag)) <= tol) & (groups[1:] == groups[:-1])]
    r = _runs(same)  # run [a, b) of repeats: samples a − 1 … b − 1 read one value
    r = r[r[:, 1] - r[:, 0] + 1 >= HELD_RUN]
    delta = np.zeros(n + 1)
    np.add.at(delta, r[:, 0] - 1, 1)
    np.add.at(delta, r[:, 1], -1)
    return np.cumsum(delta)[:n] > 0


def sliding(values: np.ndarray, w: int) -> np.ndarray:
    """Centred means of ``values`` (n, ...) over ``w`` samples (odd; the edges repeat): (n, ...)."""
    from scipy.ndimage import uniform_filter1d

    return uniform_filter1d(np.asarray(values, dtype=float), w, axis=0, mode="nearest")


def quietest_near(C: np.ndarray, f: np.ndarray, cone_deg: float) -> tuple[np.ndarray, np.ndarray]:
    """For second moments C (n, 3, 3) and unit forces f (n, 3): the share of the motion (nᵀCn / tr C)
    along the quietest of three directions within ``cone_deg`` of f — the smallest eigenvector, the
    direction of the two smallest nearest to f, f itself — and that direction: (n,), (n, 3)."""
    lam, E = np.linalg.eigh(C)
    tr = np.maximum(lam.sum(1), np.finfo(float).tiny)
    e1, e2 = E[:, :, 0], E[:, :, 1]
    a1, a2 = (e1 * f).sum(1), (e2 * f).sum(1)
    r12 = np.hypot(a1, a2)
    n12 = (a1[:, None] * e1 + a2[:, None] * e2) / np.maximum(r12, 1e-12)[:, None]
    s12 = (a1**2 * lam[:, 0] + a2**2 * lam[:, 1]) / np.maximum(r12**2, 1e-300) / tr
    sf = np.einsum("ni,nij,nj->n", f, C, f) / tr
    c = np.cos(np.radians(cone_deg))
    shares = np.stack([np.where(np.abs(a1) >= c, lam[:, 0] / tr, np.inf), np.where(r12 >= c, s12, np.inf),
                       sf], 1)
    dirs = np.stack([e1 * np.where(a1 < 0, -1.0, 1.0)[:, None], n12, f], 1)
    j = shares.argmin(1)
    pick = np.arange(len(j))
    return shares[pick, j], dirs[pick, j]


def _runs(mask: np.ndarray) -> np.ndarray:
    """[start, stop) of each run of True in ``mask`` (n,): (R, 2)."""
    edges = np.flatnonzero(np.diff(np.r_[0, mask.astype(np.int8), 0]))
    return edges.reshape(-1, 2)


def _clean(mask: np.ndarray, t: np.ndarray, gap_s: float, min_s: float) -> np.ndarray:
    """``mask`` (n,) of one demonstration with gaps shorter than ``gap_s`` (s) between runs filled
    and runs shorter than ``min_s`` dropped."""
    out = mask.copy()
    step = float(np.median(np.diff(t))) if len(t) > 1 else 0.0
    for a, b in _runs(~out):  # a loop over runs, not samples
        if 0 < a and b < len(out) and t[b] - t[a - 1] - step < gap_s:
            out[a:b] = True
    for a, b in _runs(out):
        if t[b - 1] - t[a] + step < min_s:
            out[a:b] = False
    return out


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    """Angle (degrees) between the lines along a and b."""
    c = abs(float(a @ b)) / max(float(np.linalg.norm(a) * np.linalg.norm(b)), np.finfo(float).tiny)
    return float(np.degrees(np.arccos(min(c, 1.0))))


def _baseline(mean: np.ndarray, dev: np.ndarray, C: np.ndarray, ok: np.ndarray, w: int
              ) -> tuple[np.ndarray | None, np.ndarray]:
    """The channel's baseline in one demonstration (3,) — the mean of the levels read at each end (its
    first and last EDGE_SHARE) on the windows that move less than the median there and, of those,
    vary less than the median — and the windows it was read on; None when no end (nor the rest) has
    ``w`` windows with evidence.
    ``mean`` (n, 3), ``dev`` (n,) the windows' force and its RMS deviation, C (n, 3, 3), ok (n,)."""
    n = len(mean)
    rank = np.arange(n) / max(n - 1, 1)
    sides = [np.flatnonzero((rank <= EDGE_SHARE) & ok), np.flatnonzero((rank >= 1 - EDGE_SHARE) & ok)]
    sides = [c for c in sides if len(c) >= w] or [np.flatnonzero(ok)]
    if len(sides[0]) < w:
        return None, np.zeros(0, np.int64)
    levels, used = [], []
    for cand in sides:
        trace = np.trace(C[cand], axis1=1, axis2=2)
        still = cand[trace <= np.quantile(trace, 0.5)]  # a hand that pushes moves the tool
        quiet = still[dev[still] <= np.quantile(dev[still], 0.5)]
        levels.append(np.median(mean[quiet], axis=0))
        used.append(quiet)
    return np.mean(levels, axis=0), np.concatenate(used)


def find(force: np.ndarray, U: np.ndarray, groups: np.ndarray | None = None, t: np.ndarray | None = None
         ) -> Contact:
    """The contact stretches and their rows the force (N, 3) and the velocities U (N, 3) show (module
    docstring); ``groups`` (N,) demonstration ids (contiguous), ``t`` (N,) s (None: unit steps)."""
    force, U = np.asarray(force, dtype=float), np.asarray(U, dtype=float)
    n = len(U)
    if force.shape != (n, 3) or U.shape != (n, 3):
        raise InputError(f"forces as evidence need a 3-D force and 3-D actions per sample, got {force.shape} "
                         f"and {U.shape}")
    groups = np.zeros(n, np.int64) if groups is None else np.asarray(groups)
    t = np.arange(n, dtype=float) if t is None else np.asarray(t, dtype=float)
    stale = held(force, groups)
    ids = np.unique(groups)
    D, C = np.zeros((n, 3)), np.zeros((n, 3, 3))
    ok, dev = np.zeros(n, bool), np.zeros(n)
    baseline, held_share, quiet_dev, width = {}, {}, [], {}
    outer = U[:, :, None] * U[:, None, :]
    for d in ids:  # a loop over demonstrations; each step batched over its samples
        m = np.flatnonzero(groups == d)
        held_share[int(d)] = float(stale[m].mean())
        step = float(np.median(np.diff(t[m]))) if len(m) > 1 else 1.0
        w = max(3, int(round(WINDOW_S / step)) // 2 * 2 + 1) if step > 0 else 3
        width[int(d)] = w
        mean = sliding(force[m], w)
        dev[m] = np.sqrt(np.maximum(sliding((force[m] ** 2).sum(1), w) - (mean**2).sum(1), 0.0))
        C[m] = sliding(outer[m], w)
        ok[m] = ~(sliding(stale[m].astype(float), w) > 0)
        b, quiet = _baseline(mean, dev[m], C[m], ok[m], w)
        if b is None:
            continue  # held (nearly) throughout: no evidence from this demonstration
        baseline[int(d)] = b
        D[m] = mean - b
        quiet_dev.append(dev[m][quiet])
    if not baseline:
        return Contact(np.zeros(n, bool), [], baseline, held_share)
    mag = np.linalg.norm(D, axis=1)
    noise = float(np.median(np.concatenate(quiet_dev)))
    level = max(NOISE_K * noise, LEVEL_SHARE * float(np.quantile(mag[ok], 0.9)))
    on = ok & (mag > level)
    trace = np.trace(C, axis1=1, axis2=2)
    floor = STILL_SHARE * float(np.median(trace))
    unit = D / np.maximum(mag, np.finfo(float).tiny)[:, None]
    share, _ = quietest_near(C, unit, REACTION_DEG)
    core = on & (trace > floor) & (share <= MOTION_SHARE)
    mask = np.zeros(n, bool)
    stretches: list[Stretch] = []
    for d in ids:  # a loop over demonstrations, then over its stretches
        m = np.flatnonzero(groups == d)
        cores = _clean(core[m], t[m], GAP_S, MIN_S)
        grown = np.zeros(len(m), bool)
        for a, b in _runs(cores):
            idx = m[a:b][core[m[a:b]]]
            row = _row(U[idx], D[idx])[0]
            if row is None:
                continue
            along = np.einsum("i,nij,j->n", row, C[m], row) / np.maximum(trace[m], floor)
            near = _clean(on[m] & (along <= GROW_SHARE), t[m], GAP_S, 0.0)
            near[a:b] = True
            for g0, g1 in _runs(near):
                if g0 <= a < g1:
                    grown[g0:g1] = True
        grown = _clean(grown, t[m], 0.0, MIN_S)
        for a, b in _runs(grown):
            idx = m[a:b]
            row, how = _row(U[idx], D[idx])
            if row is None:
                continue
            fbar = D[idx].mean(0)
            C_s = U[idx].T @ U[idx]
            stretches.append(Stretch(int(d), int(m[a]), int(m[b - 1]) + 1, row, fbar, _angle(row, fbar),
                                     float(row @ C_s @ row / max(np.trace(C_s), np.finfo(float).tiny)), how))
            mask[idx] = True
    return Contact(mask, stretches, baseline, held_share, level, noise)


def _row(U: np.ndarray, D: np.ndarray) -> tuple[np.ndarray | None, str]:
    """The row of a stretch and how it was read (module docstring, AGREE_DEG): the smallest
    eigenvector of Σ u uᵀ over it (velocities U (m, 3)) when it lies within AGREE_DEG of the mean
    force above baseline (D (m, 3)); else the quietest direction near the force
    (:func:`quietest_near`) when quiet enough; else None (no reaction)."""
    C = U.T @ U
    f = D.mean(0)
    f = f / max(float(np.linalg.norm(f)), np.finfo(float).tiny)
    e1 = np.linalg.eigh(C)[1][:, 0]
    e1 = e1 if e1 @ f >= 0 else -e1
    if _angle(e1, f) <= AGREE_DEG:
        return e1, f"the velocities' smallest direction, within {AGREE_DEG:g}° of the force"
    share, near = quietest_near(C[None], f[None], REACTION_DEG)
    if share[0] <= GROW_SHARE:
        return near[0], (f"the quietest direction within {REACTION_DEG:g}° of the force (the velocities' "
                         f"smallest lies {_angle(e1, f):.0f}° from it)")
    return None, f"the motion's quietest direction lies {_angle(e1, f):.0f}° from the force: no reaction"
