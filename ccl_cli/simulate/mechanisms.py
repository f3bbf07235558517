"""A hand opening a hinged door and pulling a drawer, as the TUM articulation logs record them
(issue 30): k = 2 in 3-D, the rows turning with the angle about a hinge, constant (or nearly:
a bowing rail) along a slide. What real logs add — compliance along the rows, tremor, drift,
filtered velocities — is :mod:`.realism`'s.

Magnitudes of the real logs (circle or line fitted per log; :mod:`.realism` for the
residuals): hinges of radius 0.30–0.67 m swept 57–111°, 240–770 samples, 1–2.4 mm a step, the
trials' frames 8–18 cm apart (each in its own base frame), the fitted radii of one door ±2–3 %
apart, radial residual 0.6–6.4 mm, out of plane 0.7–4 mm; drawers and sliding doors 0.45–0.6 m
of travel, 1–10 mm RMS across the line (a sliding door's rail bows 2.5 cm mid-way).
"""

from __future__ import annotations

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.learn.linalg import unit_rows
from ccl_cli.simulate import realism as rl
from ccl_cli.simulate.recordings import stroke_phase


def _timing(rng: np.random.Generator, lengths: np.ndarray, speed: tuple[float, float],
            hold_s: tuple[float, float], rate: float
            ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Rest, a minimum-jerk move of ``lengths`` (D,) m at a mean speed uniform in ``speed``, rest
    (each uniform in ``hold_s``): stamps t (N,), demo (N,), the move's start (D,) and duration (D,)."""
    n = len(lengths)
    before, after = rng.uniform(*hold_s, n), rng.uniform(*hold_s, n)
    move = lengths / rng.uniform(*speed, n)
    t, demo = rl.sampled(before + move + after, rate)
    return t, demo, before, move


def _progress(t: np.ndarray, demo: np.ndarray, start: np.ndarray, move: np.ndarray) -> np.ndarray:
    """The minimum-jerk phase σ ∈ [0, 1] of each sample's move (0 before it, 1 after)."""
    return stroke_phase((t - start[demo]) / move[demo])[0]


def _check_mechanism(n_demos: int, speed: tuple[float, float], hold_s: tuple[float, float], offset: float,
                     **effects: object) -> None:
    rl.check("n_demos", n_demos, isinstance(n_demos, int) and n_demos >= 1, "an integer ≥ 1")
    rl.check("speed", speed, len(speed) == 2 and 0 < speed[0] <= speed[1], "a range (low, high) > 0 m/s")
    rl.check("hold_s", hold_s, len(hold_s) == 2 and 0 <= hold_s[0] <= hold_s[1], "a range (low, high) ≥ 0 s")
    rl.check("offset", offset, np.isfinite(offset) and offset >= 0, "a length ≥ 0 (m)")
    rl.check_effects(**effects)  # type: ignore[arg-type]


def hinge(
    n_demos: int = 5,
    rate: float = 30.0,
    radius: tuple[float, float] = (0.3, 0.67),
    grasp: float = 0.015,
    height: float = 0.05,
    offset: float = 0.1,
    sweep_deg: tuple[float, float] = (60.0, 120.0),
    speed: tuple[float, float] = (0.03, 0.06),
    hold_s: tuple[float, float] = (0.5, 2.0),
    noise: float = 4e-4,
    compliance: float = 2e-3,
    compliance_hz: tuple[float, float] = (0.1, 1.0),
    tremor: float = 0.0,
    drift: float = 0.0,
    velocities: str = "derived",
    filter_hz: float = 5.0,
    seed: int = 0,
) -> Demonstrations:
    """A hand opening one hinged door ``n_demos`` times (k = 2: the axis and the radial row).

    The door's radius R is uniform in ``radius`` (m); each demonstration grasps it at its own
    radius R + U(±``grasp``) (the real logs' radii spread ±2–3 %, ±1–1.7 cm) and height
    U(±``height``) along the axis, starts within ±5° of
    closed and sweeps its own angle, uniform in ``sweep_deg`` (all the same way), by a
    minimum-jerk move at a mean speed uniform in ``speed`` (m/s) between rests of ``hold_s``
    s. Each trial is recorded in its own frame: the whole scene is translated by U(±``offset``)
    m per axis (the trials' frames differ by a translation; the axis keeps its direction, a
    seeded one). With the defaults: 180–840 samples a demonstration at 30 Hz, 1–2 mm a step.

    The door flexes and the grasp gives: ``compliance`` (m RMS, band ``compliance_hz``) along
    the radius and the axis; ``tremor``, ``drift``, ``noise``, ``velocities`` and
    ``filter_hz`` as in :mod:`.realism`.

    Truth per sample: A (N, 2, 3) the axis and the radial direction at the door's angle, N = I
    − AᵀA; of the true velocity ẋ (with compliance and tremor), b = Aẋ, v = Aᵀb, w = π = ẋ − v.
    ``metadata["demos"]``: each one's centre (the hinge in its frame), radius, height, sweep.
    """
    effects = dict(noise=noise, compliance=compliance, band=tuple(compliance_hz), tremor=tremor, drift=drift,
                   velocities=velocities, filter_hz=filter_hz)
    _check_mechanism(n_demos, speed, hold_s, offset, rate=rate, **effects)
    rl.check("radius", radius, len(radius) == 2 and 0 < radius[0] <= radius[1], "a range (low, high) > 0 m")
    rl.check("grasp", grasp, 0 <= grasp < radius[0], "a length ≥ 0 below the smallest radius (m)")
    rl.check("sweep_deg", sweep_deg, len(sweep_deg) == 2 and 0 < sweep_deg[0] <= sweep_deg[1] <= 180,
             "a range (low, high) in (0°, 180°]")
    rng = rl.stream(seed, "path")
    R_frame = rl.random_rotation(rl.stream(seed, "frame"))
    door = rng.uniform(*radius)
    r = door + rng.uniform(-grasp, grasp, n_demos)
    z = rng.uniform(-height, height, n_demos)
    theta0 = np.radians(rng.uniform(-5.0, 5.0, n_demos))
    sweep = np.radians(rng.uniform(*sweep_deg, n_demos)) * rng.choice([-1.0, 1.0])
    hinge_at = rng.uniform(-0.5, 0.5, 3) + rng.uniform(-offset, offset, (n_demos, 3))  # per trial's frame
    t, demo, start, move = _timing(rng, r * np.abs(sweep), speed, hold_s, rate)
    give = rl.compliance_band(seed, n_demos, 2, compliance, effects["band"])
    shake = rl.tremor_band(seed, n_demos, 3, tremor)

    def local(ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The door's angle θ (N,) and the hand in the door's frame (N, 3) at stamps ts."""
        theta = theta0[demo] + sweep[demo] * _progress(ts, demo, start, move)
        c = give.at(ts, demo)[0]
        rad = r[demo] + c[:, 1]
        return theta, np.c_[rad * np.cos(theta), rad * np.sin(theta), z[demo] + c[:, 0]]

    def path(ts: np.ndarray) -> np.ndarray:
        return local(ts)[1] @ R_frame.T + hinge_at[demo] + shake.at(ts, demo)[0]

    theta, _ = local(t)
    x_true = path(t)
    xdot = rl.velocity_of(path, t)
    axis = R_frame[:, 2]
    radial = np.c_[np.cos(theta), np.sin(theta), np.zeros_like(theta)] @ R_frame.T
    rows = np.stack([np.broadcast_to(axis, radial.shape), radial], 1)
    X, U, derivative, how = rl.observe(seed, t, demo, x_true, rate=rate, noise=noise, drift=drift,
                                       velocities=velocities, filter_hz=filter_hz)
    meta = {"simulated": "hinge", "rate_hz": rate, "n_constraints": 2, "axis": axis.tolist(),
            "door_radius_m": float(door),
            "demos": [{"centre": hinge_at[d].tolist(), "radius_m": float(r[d]), "height_m": float(z[d]),
                       "sweep_deg": float(np.degrees(abs(sweep[d])))} for d in range(n_demos)],
            "effects": rl.effects_record(how=how, **effects), "faults": []}
    return rl.recording(X, U, demo, t, rl.constrained_truth(xdot, rows), derivative, meta)


def slide(
    n_demos: int = 5,
    rate: float = 30.0,
    travel: tuple[float, float] = (0.4, 0.5),
    offset: float = 0.1,
    bow: float = 5e-3,
    speed: tuple[float, float] = (0.03, 0.06),
    hold_s: tuple[float, float] = (0.5, 2.0),
    noise: float = 4e-4,
    compliance: float = 1.5e-3,
    compliance_hz: tuple[float, float] = (0.1, 1.0),
    tremor: float = 0.0,
    drift: float = 0.0,
    velocities: str = "derived",
    filter_hz: float = 5.0,
    seed: int = 0,
) -> Demonstrations:
    """A hand pulling one drawer (or sliding door) open ``n_demos`` times (k = 2: the two
    directions across its rail).

    The rail runs along a seeded direction e; each demonstration travels its own length,
    uniform in ``travel`` (m), by a minimum-jerk move at a mean speed uniform in ``speed`` (m/s)
    between rests of ``hold_s`` s, in its own frame (translated by U(±``offset``) m per axis).
    The rail bows: the hand leaves the straight line by β sin(πs/L) at travel s of L, β uniform
    in ±``bow`` (m) along a direction across e drawn per demonstration (a rail that flexes, a
    regrasp: the real sliding door rises 2.5 cm mid-way).

    The drawer rattles in its rail: ``compliance`` (m RMS, band ``compliance_hz``) along the
    two rows; ``tremor``, ``drift``, ``noise``, ``velocities`` and ``filter_hz`` as in
    :mod:`.realism`.

    Truth per sample: A (N, 2, 3) an orthonormal basis across the bowed rail's tangent (within
    atan(πβ/L) ≤ 2.3° of e for the defaults), N = I − AᵀA; b, v, w, π of the true velocity as in
    :func:`hinge`. ``metadata``: the direction e, each demonstration's travel, bow and frame.
    """
    effects = dict(noise=noise, compliance=compliance, band=tuple(compliance_hz), tremor=tremor, drift=drift,
                   velocities=velocities, filter_hz=filter_hz)
    _check_mechanism(n_demos, speed, hold_s, offset, rate=rate, **effects)
    rl.check("travel", travel, len(travel) == 2 and 0 < travel[0] <= travel[1], "a range (low, high) > 0 m")
    rl.check("bow", bow, np.isfinite(bow) and 0 <= bow < travel[0] / 4,
             "a length ≥ 0 below a quarter of the travel (m)")
    rng = rl.stream(seed, "path")
    R_frame = rl.random_rotation(rl.stream(seed, "frame"))
    e, across = R_frame[:, 0], R_frame[:, 1:].T  # the rail and two directions across it
    length = rng.uniform(*travel, n_demos)
    beta = rng.uniform(-bow, bow, n_demos)
    turn = rng.uniform(0, 2 * np.pi, n_demos)
    bend = np.cos(turn)[:, None] * across[0] + np.sin(turn)[:, None] * across[1]  # (D, 3) ⊥ e
    side = np.cross(e, bend)  # (D, 3), across e and the bow
    origin = rng.uniform(-0.5, 0.5, 3) + rng.uniform(-offset, offset, (n_demos, 3))
    t, demo, start, move = _timing(rng, length, speed, hold_s, rate)
    give = rl.compliance_band(seed, n_demos, 2, compliance, effects["band"])
    shake = rl.tremor_band(seed, n_demos, 3, tremor)

    def rails(ts: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The point on the bowed rail (N, 3) and the row across it in the bow's plane (N, 3)."""
        s = length[demo] * _progress(ts, demo, start, move)
        arg = np.pi * s / length[demo]
        on = origin[demo] + s[:, None] * e + (beta[demo] * np.sin(arg))[:, None] * bend[demo]
        slope = beta[demo] * np.pi / length[demo] * np.cos(arg)  # d(bow)/ds
        return on, unit_rows(bend[demo] - slope[:, None] * e)

    def path(ts: np.ndarray) -> np.ndarray:
        on, row = rails(ts)
        c = give.at(ts, demo)[0]
        return on + c[:, :1] * row + c[:, 1:] * side[demo] + shake.at(ts, demo)[0]

    _, row = rails(t)
    rows = np.stack([row, side[demo]], 1)
    x_true = path(t)
    xdot = rl.velocity_of(path, t)
    X, U, derivative, how = rl.observe(seed, t, demo, x_true, rate=rate, noise=noise, drift=drift,
                                       velocities=velocities, filter_hz=filter_hz)
    meta = {"simulated": "slide", "rate_hz": rate, "n_constraints": 2, "direction": e.tolist(),
            "demos": [{"origin": origin[d].tolist(), "travel_m": float(length[d]), "bow_m": float(beta[d]),
                       "bow_direction": bend[d].tolist()} for d in range(n_demos)],
            "effects": rl.effects_record(how=how, **effects), "faults": []}
    return rl.recording(X, U, demo, t, rl.constrained_truth(xdot, rows), derivative, meta)
