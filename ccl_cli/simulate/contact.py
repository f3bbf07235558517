"""A hand that comes to a surface, works on it and leaves (issue 30): approach (free) → contact
(strokes on a plane or in a bowl, k = 1) → retract (free), in task space, with what real logs
add (:mod:`.realism`): a finger pad or tool that gives along the normal, tremor, drift,
filtered velocities.

Magnitudes of the real logs: a KUKA LWR wiping a rim cover, contact 45–76 % of each labelled
demonstration (a grating log: 73–82 %), 13–31 N along the normal, the positions 1.4–12.7 mm
RMS off each wipe's plane, almost all of it below 2 Hz (white part 0.01 mm); a Trakstar on a
fingertip tracing on a flat board: 0.7 mm RMS in 8–12 Hz along the normal and local planes ~20°
from the global one.
"""

from __future__ import annotations

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.simulate import realism as rl
from ccl_cli.simulate.recordings import stroke_phase
from ccl_cli.simulate.tracker import _tilt, _tracker_path, _tracker_segments

#: Phases of a demonstration, in order.
PHASES = ("approach", "contact", "retract")
#: Seconds over which the pressing motion fades in and out at the ends of the contact.
RAMP_S = 0.3
SURFACES = ("plane", "sphere")


def _ramp(s: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Smoothstep h = s²(3 − 2s) of s clipped to [0, 1], and dh/ds."""
    s = np.clip(s, 0.0, 1.0)
    return s**2 * (3 - 2 * s), 6 * s * (1 - s)


def contact_phases(
    n_demos: int = 5,
    rate: float = 100.0,
    surface: str = "plane",
    tilt_deg: float = 20.0,
    radius: float = 0.25,
    approach_s: tuple[float, float] = (1.5, 2.5),
    contact_s: tuple[float, float] = (8.0, 12.0),
    retract_s: tuple[float, float] = (1.5, 2.5),
    height: tuple[float, float] = (0.1, 0.2),
    extent: float = 0.08,
    speed: tuple[float, float] = (0.03, 0.12),
    pause: tuple[float, float] = (0.3, 1.5),
    noise: float = 3e-4,
    compliance: float = 1.5e-3,
    compliance_hz: tuple[float, float] = (0.1, 2.0),
    tremor: float = 4e-4,
    drift: float = 0.0,
    velocities: str = "derived",
    filter_hz: float = 5.0,
    seed: int = 0,
) -> Demonstrations:
    """``n_demos`` demonstrations of a hand working on one ``surface``: a table (``plane``,
    tilted by ``tilt_deg`` about a seeded horizontal axis) or a bowl (``sphere``, the inside of
    a sphere of ``radius`` m, tilted the same way). Each demonstration:

    * **approach** (``approach_s`` s, uniform): a minimum-jerk move from a start ``height`` m
      (uniform) off the surface, along its normal and up to 5 cm aside, to a point on it;
    * **contact** (``contact_s`` s): strokes on the surface from that point — straight moves,
      ellipses and figure-eights within ``extent`` m, mean speeds uniform in ``speed`` m/s,
      pauses of ``pause`` s (the tracker simulations' scripts, each demonstration its own) —
      while the pad gives along the normal: ``compliance`` m RMS in ``compliance_hz``, faded in
      and out over 0.3 s;
    * **retract** (``retract_s`` s): a minimum-jerk move away by a new ``height`` along the
      normal and up to 5 cm aside.

    With the defaults contact is 70–85 % of each demonstration. ``tremor`` (the hand's, in
    every phase), ``drift``, ``noise``, ``velocities`` and ``filter_hz`` as in :mod:`.realism`.

    Truth per sample: N = I − nnᵀ in contact (n the surface's normal at the point below the
    hand) and I in approach and retract (N, 3, 3); of the true velocity ẋ, w = π = Nẋ and
    v = ẋ − w (A is not stored: its row count changes with the phase). ``metadata["phases"]``:
    each demonstration's [start, end) s of the three phases; ``metadata["normal"]`` the
    table's normal (``plane``) or the bowl's axis (``sphere``).
    """
    effects = dict(noise=noise, compliance=compliance, band=tuple(compliance_hz), tremor=tremor, drift=drift,
                   velocities=velocities, filter_hz=filter_hz)
    rl.check("surface", surface, surface in SURFACES, f"one of {', '.join(SURFACES)}")
    rl.check("n_demos", n_demos, isinstance(n_demos, int) and n_demos >= 1, "an integer ≥ 1")
    for name, rng_ in (("approach_s", approach_s), ("contact_s", contact_s), ("retract_s", retract_s),
                       ("height", height), ("speed", speed)):
        rl.check(name, rng_, len(rng_) == 2 and 0 < rng_[0] <= rng_[1], "a range (low, high) > 0")
    rl.check("contact_s", contact_s, contact_s[0] > 2 * RAMP_S, f"longer than {2 * RAMP_S:g} s")
    rl.check("radius", radius, surface == "plane" or radius > 2 * extent, "larger than twice the extent (m)")
    rl.check_effects(rate=rate, **effects)
    rng = rl.stream(seed, "path")
    R = _tilt(rng, tilt_deg)
    centre = rng.uniform(-0.3, 0.3, 3)
    durations = np.stack([rng.uniform(*approach_s, n_demos), rng.uniform(*contact_s, n_demos),
                          rng.uniform(*retract_s, n_demos)], 1)
    starts = np.cumsum(durations, 1) - durations  # (D, 3) start of each phase
    anchor = rng.uniform(-0.3, 0.3, (n_demos, 2)) * extent
    scripts = [_tracker_segments(rng, float(durations[d, 1]), extent, speed, pause, (0.5, 1.0))
               for d in range(n_demos)]
    lift = [rng.uniform(*height, n_demos), rng.uniform(*height, n_demos)]
    aside = rng.uniform(-0.05, 0.05, (2, n_demos, 2))
    t, demo = rl.sampled(durations.sum(1), rate)
    give = rl.compliance_band(seed, n_demos, 1, compliance, effects["band"])
    shake = rl.tremor_band(seed, n_demos, 3, tremor)
    phase = (t >= starts[demo, 1]).astype(int) + (t >= starts[demo, 2]).astype(int)

    def on_surface(ab: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Plane coordinates (N, 2) → the point on the surface (N, 3) and the unit normal there
        pointing to the free side (N, 3)."""
        if surface == "plane":
            return centre + ab @ R[:, :2].T, np.broadcast_to(R[:, 2], (len(ab), 3))
        g = np.c_[ab, np.full(len(ab), -radius)]
        d = g / np.linalg.norm(g, axis=1, keepdims=True)  # from the bowl's centre to the surface
        return centre + (radius * (d + np.array([0.0, 0.0, 1.0]))) @ R.T, -d @ R.T

    def strokes(ts: np.ndarray) -> np.ndarray:
        """The contact phase's plane coordinates (N, 2) at stamps ts (clamped to the phase)."""
        tc = np.clip(ts - starts[demo, 1], 0.0, durations[demo, 1])
        ab = np.zeros((len(ts), 2))
        for d, script in enumerate(scripts):  # one vectorised call per demonstration
            m = demo == d
            P = _tracker_path(script, np.r_[0.0, tc[m]])[0]
            ab[m] = anchor[d] + P[1:] - P[0]
        return ab

    def path(ts: np.ndarray) -> np.ndarray:
        on, n = on_surface(strokes(ts))
        # pressing: the pad gives along −n, faded in and out at the ends of the contact
        into = (ts - starts[demo, 1]) / RAMP_S
        out_of = (starts[demo, 2] - ts) / RAMP_S
        fade = _ramp(into)[0] * _ramp(out_of)[0]
        x = on - (fade * give.at(ts, demo)[0][:, 0])[:, None] * n
        # before and after the contact the strokes hold their first and last point: the hand
        # comes down to it along the normal (and aside), and leaves from it the same way
        e1, e2 = R[:, 0], R[:, 1]
        s_in = stroke_phase((ts - starts[demo, 0]) / durations[demo, 0])[0]
        s_out = stroke_phase((ts - starts[demo, 2]) / durations[demo, 2])[0]
        off_in = lift[0][demo, None] * n + aside[0, demo, :1] * e1 + aside[0, demo, 1:] * e2
        off_out = lift[1][demo, None] * n + aside[1, demo, :1] * e1 + aside[1, demo, 1:] * e2
        x = np.where((ts < starts[demo, 1])[:, None], on + (1 - s_in)[:, None] * off_in, x)
        x = np.where((ts >= starts[demo, 2])[:, None], on + s_out[:, None] * off_out, x)
        return x + shake.at(ts, demo)[0]

    x_true = path(t)
    xdot = rl.velocity_of(path, t)
    n_at = on_surface(strokes(t))[1]
    touching = phase == 1
    N = np.where(touching[:, None, None], np.eye(3) - np.einsum("ni,nj->nij", n_at, n_at), np.eye(3))
    w = np.einsum("nij,nj->ni", N, xdot)
    truth = {"N": N, "pi": w, "w": w.copy(), "v": xdot - w}
    X, U, derivative, how = rl.observe(seed, t, demo, x_true, rate=rate, noise=noise, drift=drift,
                                       velocities=velocities, filter_hz=filter_hz)
    ends = np.c_[starts, durations.sum(1)]
    meta = {"simulated": "contact_phases", "surface": surface, "rate_hz": rate, "n_constraints": 1,
            "normal": R[:, 2].tolist(), "centre": centre.tolist(),
            "phases": [{name: [float(ends[d, i]), float(ends[d, i + 1])] for i, name in enumerate(PHASES)}
                       for d in range(n_demos)],
            "contact_share": float(touching.mean()),
            "effects": rl.effects_record(how=how, **effects), "faults": []}
    return rl.recording(X, U, demo, t, truth, derivative, meta)


def phase_of(d: Demonstrations) -> np.ndarray:
    """The phase of each sample of a :func:`contact_phases` recording (N,): 0 approach, 1
    contact, 2 retract (from ``metadata["phases"]``, by demonstration and time)."""
    out = np.zeros(d.n_samples, dtype=np.int64)
    for i, p in enumerate(d.metadata["phases"]):
        m = d.demo == d.demo_ids[i]
        out[m] = (d.t[m] >= p["contact"][0]).astype(int) + (d.t[m] >= p["retract"][0]).astype(int)
    return out
