"""Free motion with what real logs add (issue 30): nothing constrains it (N = I), yet it need not
move evenly in every direction — the negative controls a rule for k must leave at 0.

Magnitudes of the real logs: a KUKA LWR reaching a sink from 11 scattered starts, 624–803
samples at 103 Hz, per demonstration 0.13–0.21 m/s RMS along its two main directions and
0.022–0.042 m/s along the third (nearly planar reaches); handwriting on a Wacom tablet at
133–200 Hz, looped cursive strokes of a few mm a loop at ~3–5 loops per second.
"""

from __future__ import annotations

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.learn.linalg import unit_rows
from ccl_cli.simulate import realism as rl
from ccl_cli.simulate.recordings import stroke_phase


def _free_truth(xdot: np.ndarray) -> dict[str, np.ndarray]:
    """N = I, π = w = ẋ, v = 0."""
    return {"N": np.eye(xdot.shape[1]), "pi": xdot, "w": xdot.copy(), "v": np.zeros_like(xdot)}


def reach_goal(
    n_demos: int = 11,
    rate: float = 100.0,
    spread: float = 0.8,
    fan_deg: float = 60.0,
    flatness: float = 0.1,
    curvature: float = 0.35,
    twist: float = 0.06,
    duration_s: tuple[float, float] = (5.0, 7.0),
    hold_s: tuple[float, float] = (0.3, 1.0),
    noise: float = 2e-4,
    tremor: float = 5e-5,
    drift: float = 0.0,
    velocities: str = "derived",
    filter_hz: float = 5.0,
    seed: int = 0,
) -> Demonstrations:
    """Reaching one goal from ``n_demos`` scattered starts (a kinesthetic "sink" motion): no
    constraint.

    The starts lie at 0.9–1.1 × ``spread`` m from the goal, within a fan of ``fan_deg`` in a
    seeded plane, and ``flatness`` × ``spread`` (RMS) off it; each reach is a minimum-jerk move
    of ``duration_s`` s (uniform) whose path bows aside by ``curvature`` × its length (sin πσ, a
    random direction across the move) and out of that plane by ``twist`` × its length (sin 2πσ),
    then rests ``hold_s`` s on the goal. With the defaults a reach of 0.7–0.9 m moves 0.03–0.05
    m/s RMS along its least-used direction against 0.08–0.19 m/s along the others (the real
    reaches: 0.025–0.063 against 0.13–0.47).
    ``tremor``, ``drift``, ``noise``, ``velocities``, ``filter_hz`` as in :mod:`.realism`.

    Truth: N = I (3, 3), π = w = ẋ (the true velocity, tremor included), v = 0.
    """
    effects = dict(noise=noise, compliance=0.0, band=(1.0, 1.0), tremor=tremor, drift=drift,
                   velocities=velocities, filter_hz=filter_hz)
    rl.check("n_demos", n_demos, isinstance(n_demos, int) and n_demos >= 1, "an integer ≥ 1")
    rl.check("spread", spread, np.isfinite(spread) and spread > 0, "a length > 0 (m)")
    rl.check("duration_s", duration_s, len(duration_s) == 2 and 0 < duration_s[0] <= duration_s[1],
             "a range (low, high) > 0 s")
    rl.check("hold_s", hold_s, len(hold_s) == 2 and 0 <= hold_s[0] <= hold_s[1], "a range (low, high) ≥ 0 s")
    rl.check_effects(rate=rate, **effects)
    rng = rl.stream(seed, "path")
    R = rl.random_rotation(rl.stream(seed, "frame"))
    goal = rng.uniform(-0.3, 0.3, 3)
    ang = rng.uniform(0, 2 * np.pi) + np.radians(fan_deg) * rng.uniform(-0.5, 0.5, n_demos)
    dist = spread * rng.uniform(0.9, 1.1, n_demos)
    local = np.c_[dist * np.cos(ang), dist * np.sin(ang), rng.normal(scale=flatness * spread, size=n_demos)]
    step = -local @ R.T  # (D, 3) from each start to the goal
    length = np.linalg.norm(step, axis=1)
    across = unit_rows(np.cross(step, rng.normal(size=(n_demos, 3))))
    out_of = np.cross(unit_rows(step), across)  # across the move and the bow
    bow = curvature * length[:, None] * (across * rng.choice([-1.0, 1.0], (n_demos, 1)))
    turn = twist * length[:, None] * out_of * rng.choice([-1.0, 1.0], (n_demos, 1))
    move = rng.uniform(*duration_s, n_demos)
    t, demo = rl.sampled(move + rng.uniform(*hold_s, n_demos), rate)
    shake = rl.tremor_band(seed, n_demos, 3, tremor)

    def path(ts: np.ndarray) -> np.ndarray:
        s = stroke_phase(ts / move[demo])[0][:, None]
        return (goal - step[demo] + s * step[demo] + np.sin(np.pi * s) * bow[demo]
                + np.sin(2 * np.pi * s) * turn[demo] + shake.at(ts, demo)[0])

    x_true = path(t)
    xdot = rl.velocity_of(path, t)
    X, U, derivative, how = rl.observe(seed, t, demo, x_true, rate=rate, noise=noise, drift=drift,
                                       velocities=velocities, filter_hz=filter_hz)
    meta = {"simulated": "reach_goal", "rate_hz": rate, "n_constraints": 0, "goal": goal.tolist(),
            "effects": rl.effects_record(how=how, **effects), "faults": []}
    return rl.recording(X, U, demo, t, _free_truth(xdot), derivative, meta)


def handwriting(
    n_words: int = 4,
    rate: float = 133.0,
    duration_s: tuple[float, float] = (1.5, 3.0),
    size: float = 4e-3,
    loops_hz: tuple[float, float] = (3.0, 5.0),
    slant_deg: float = 15.0,
    noise: float = 2e-5,
    tremor: float = 5e-5,
    drift: float = 0.0,
    velocities: str = "derived",
    filter_hz: float = 5.0,
    seed: int = 0,
) -> Demonstrations:
    """Cursive words written on a tablet, one demonstration each: free 2-D motion (N = I).

    A word of ``duration_s`` s (uniform) is a row of loops: the pen advances along the line
    while circling at a rate uniform in ``loops_hz`` (Hz), x(τ) = vτ + a(τ) cos φ(τ),
    y(τ) = b(τ) sin φ(τ), slanted by ``slant_deg``; the loop sizes a, b ~ ``size`` m vary
    slowly (±40 %) along the word, and the word starts and ends at rest (τ runs on a
    minimum-jerk clock). Each word is on its own line (offset across). ``noise`` (the tablet's
    resolution), ``tremor``, ``drift``, ``velocities``, ``filter_hz`` as in :mod:`.realism`.

    Truth: N = I (2, 2), π = w = ẋ, v = 0.
    """
    effects = dict(noise=noise, compliance=0.0, band=(1.0, 1.0), tremor=tremor, drift=drift,
                   velocities=velocities, filter_hz=filter_hz)
    rl.check("n_words", n_words, isinstance(n_words, int) and n_words >= 1, "an integer ≥ 1")
    rl.check("duration_s", duration_s, len(duration_s) == 2 and 0 < duration_s[0] <= duration_s[1],
             "a range (low, high) > 0 s")
    rl.check("size", size, np.isfinite(size) and size > 0, "a length > 0 (m)")
    rl.check("loops_hz", loops_hz, len(loops_hz) == 2 and 0 < loops_hz[0] <= loops_hz[1],
             "a range (low, high) > 0 Hz")
    rl.check_effects(rate=rate, **effects)
    rng = rl.stream(seed, "path")
    dur = rng.uniform(*duration_s, n_words)
    freq = rng.uniform(*loops_hz, n_words)
    phase0 = rng.uniform(0, 2 * np.pi, n_words)
    line = np.c_[rng.uniform(-0.02, 0.02, n_words), -0.015 * np.arange(n_words)]
    sizes = rl.Band.draw(rng, n_words, 2, 0.4 / np.sqrt(2), (0.2, 1.0))  # slow ±40 % changes
    c, s_ = np.cos(np.radians(slant_deg)), np.sin(np.radians(slant_deg))
    t, demo = rl.sampled(dur, rate)
    shake = rl.tremor_band(seed, n_words, 2, tremor)

    def path(ts: np.ndarray) -> np.ndarray:
        tau = dur[demo] * stroke_phase(ts / dur[demo])[0]  # the word's own clock, at rest at both ends
        phi = 2 * np.pi * freq[demo] * tau + phase0[demo]
        ab = size * (1.0 + sizes.at(tau, demo)[0])
        x = 1.2 * size * freq[demo] * tau + ab[:, 0] * np.cos(phi)  # 1.2 × size a loop along the line
        y = ab[:, 1] * np.sin(phi)
        return line[demo] + np.c_[x + s_ * y, c * y] + shake.at(ts, demo)[0]

    x_true = path(t)
    xdot = rl.velocity_of(path, t)
    X, U, derivative, how = rl.observe(seed, t, demo, x_true, rate=rate, noise=noise, drift=drift,
                                       velocities=velocities, filter_hz=filter_hz)
    meta = {"simulated": "handwriting", "rate_hz": rate, "n_constraints": 0,
            "effects": rl.effects_record(how=how, **effects), "faults": []}
    return rl.recording(X, U, demo, t, _free_truth(xdot), derivative, meta)
