"""Realistic tracker recordings and a recording at rest, with ground truth.

A finger with a tracker sensor traces strokes on a plane or a sphere: the noise is on the
positions and the velocities are derived from them as the readers do. ``arm_at_rest`` is a
recording with nothing to learn (for the data diagnostics).
"""

from __future__ import annotations

from functools import partial
from typing import Literal

import numpy as np

from ccl_cli.dataset import Demonstrations, Derivative
from ccl_cli.errors import ConfigError
from ccl_cli.io.derivative import local_polynomial_derivative, window_for_rate
from ccl_cli.learn import defaults
from ccl_cli.learn.kinematics import SevenDofArm
from ccl_cli.learn.linalg import nullspace_projection, unit_rows
from ccl_cli.learn.params import Interval, out_of_range

# -- realistic tracker recordings --------------------------------------------------------

#: Half the time span (s) of the default derivative window, shared with the readers.
DERIVATIVE_HALF_SPAN_S = defaults.DERIVATIVE_HALF_SPAN_S

#: Shapes of the strokes a tracker simulation draws (codes in the segment table).
_PAUSE, _LINE, _CIRCLE, _EIGHT = 0, 1, 2, 3


def _tracker_segments(rng: np.random.Generator, duration: float, extent: float,
                      speed: tuple[float, float], pause: tuple[float, float],
                      aspect: tuple[float, float]) -> dict[str, np.ndarray]:
    """A random script of strokes in surface coordinates (a, b) (metres) filling ``duration`` s.

    The finger moves from anchor to anchor in straight strokes; at each anchor it traces a
    circle or a figure-eight (1–3 loops, radius 3–7 cm, squashed across by a ratio drawn
    from ``aspect``) that starts and ends at the anchor, and pauses (``pause`` s, uniform)
    with probability ½ after each stroke. Every stroke starts and ends at rest, so the path
    and its velocity are continuous.
    Returns the segment table: kind, start time, duration, anchor (·, 2) and shape parameters.
    """
    rows: list[tuple[float, ...]] = []
    t, anchor = 0.0, rng.uniform(-0.3, 0.3, 2) * extent  # start near the middle

    def add(kind: int, dur: float, d: np.ndarray | None = None, r: float = 0.0, k: float = 0.0,
            ang: float = 0.0, asp: float = 1.0) -> None:
        nonlocal t
        d = np.zeros(2) if d is None else d
        rows.append((kind, t, dur, anchor[0], anchor[1], d[0], d[1], r, k, ang, asp))
        t += dur

    while t < duration:
        radius = np.sqrt(rng.uniform(0.0, 1.0)) * extent
        target = radius * np.array([np.cos(a := rng.uniform(0, 2 * np.pi)), np.sin(a)])
        d = target - anchor
        add(_LINE, max(np.linalg.norm(d) / rng.uniform(*speed), 0.3), d)
        anchor = target
        if rng.uniform() < 0.5:
            add(_PAUSE, rng.uniform(*pause))
        kind = _CIRCLE if rng.uniform() < 0.5 else _EIGHT
        r = rng.uniform(0.03, 0.07)
        loops = int(rng.integers(1, 4))
        direction = rng.choice([-1.0, 1.0])
        length = (2 * np.pi if kind == _CIRCLE else 6.1) * r * loops
        add(kind, length / rng.uniform(*speed), r=r, k=direction * loops, ang=rng.uniform(0, 2 * np.pi),
            asp=rng.uniform(*aspect))
        if rng.uniform() < 0.5:
            add(_PAUSE, rng.uniform(*pause))
    table = np.array(rows, dtype=float)
    return {"kind": table[:, 0].astype(int), "start": table[:, 1], "dur": table[:, 2],
            "anchor": table[:, 3:5], "d": table[:, 5:7], "r": table[:, 7], "k": table[:, 8],
            "angle": table[:, 9], "aspect": table[:, 10]}


def _tracker_path(seg: dict[str, np.ndarray], t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Position P (N, 2) and velocity Ṗ (N, 2) in surface coordinates at times ``t`` (N,).

    Within a stroke of duration D the phase is σ(τ) = τ − sin(2πτ)/2π, τ = (t − t₀)/D, so the
    speed rises from 0 to twice its mean and back to 0 (dσ/dτ = 1 − cos 2πτ). Shapes, with
    θ = 2π|k|σ, ς = sign k and aspect ratio ρ: line P = σd; ellipse P = R(α)[r(1 − cos θ),
    −ςρ r sin θ]; figure-eight (Gerono) P = R(α)[ς r sin θ, ρ (r/2) sin 2θ]; pause P = 0;
    all added to the anchor.
    """
    i = np.clip(np.searchsorted(seg["start"], t, side="right") - 1, 0, len(seg["start"]) - 1)
    dur = seg["dur"][i]
    tau = np.clip((t - seg["start"][i]) / dur, 0.0, 1.0)
    sigma = tau - np.sin(2 * np.pi * tau) / (2 * np.pi)
    dsigma = (1.0 - np.cos(2 * np.pi * tau)) / dur  # dσ/dt
    kind, r, k, ang = seg["kind"][i], seg["r"][i], seg["k"][i], seg["angle"][i]
    theta = 2 * np.pi * np.abs(k) * sigma
    dtheta = 2 * np.pi * np.abs(k)  # dθ/dσ
    P = np.zeros((len(t), 2))
    dP = np.zeros((len(t), 2))  # dP/dσ
    line = kind == _LINE
    P[line] = sigma[line, None] * seg["d"][i[line]]
    dP[line] = seg["d"][i[line]]
    shape = (kind == _CIRCLE) | (kind == _EIGHT)
    th, rs, asp, sgn = theta[shape], r[shape], seg["aspect"][i[shape]], np.sign(k[shape])
    circ = (kind == _CIRCLE)[shape]
    local = np.where(circ[:, None],
                     np.stack([rs * (1 - np.cos(th)), -sgn * asp * rs * np.sin(th)], 1),
                     np.stack([sgn * rs * np.sin(th), 0.5 * asp * rs * np.sin(2 * th)], 1))
    dlocal = dtheta[shape, None] * np.where(circ[:, None],
                                            np.stack([rs * np.sin(th), -sgn * asp * rs * np.cos(th)], 1),
                                            np.stack([sgn * rs * np.cos(th), asp * rs * np.cos(2 * th)], 1))
    c, s = np.cos(ang[shape]), np.sin(ang[shape])
    rot = np.stack([np.stack([c, -s], 1), np.stack([s, c], 1)], 1)  # (n, 2, 2)
    P[shape] = np.einsum("nij,nj->ni", rot, local)
    dP[shape] = np.einsum("nij,nj->ni", rot, dlocal)
    return seg["anchor"][i] + P, dP * dsigma[:, None]


def _tilt(rng: np.random.Generator, tilt_deg: float) -> np.ndarray:
    """Rotation (3, 3) tilting the z axis by ``tilt_deg`` about a random horizontal axis."""
    az = rng.uniform(0, 2 * np.pi)
    axis = np.array([np.cos(az), np.sin(az), 0.0])
    th = np.deg2rad(tilt_deg)
    K = np.array([[0, -axis[2], axis[1]], [axis[2], 0, -axis[0]], [-axis[1], axis[0], 0]])
    return np.eye(3) + np.sin(th) * K + (1 - np.cos(th)) * K @ K


def _wobble(rng: np.random.Generator, t: np.ndarray, std: float) -> np.ndarray:
    """A slow random signal (N,) of std ``std``: five sines of 0.1–1 Hz with random phases."""
    f = rng.uniform(0.1, 1.0, 5)
    ph = rng.uniform(0, 2 * np.pi, 5)
    amp = rng.uniform(0.5, 1.0, 5)
    sig = (amp * np.sin(2 * np.pi * f * t[:, None] + ph)).sum(1)
    return std * sig / np.sqrt((amp**2).sum() / 2)


_AT_LEAST_0 = Interval(0, None)


def _tracker(surface: str, *, duration: float, rate: float, noise: float, n_recordings: int,
             tilt_deg: float, radius: float, extent: float, speed: tuple[float, float],
             pause: tuple[float, float], aspect: tuple[float, float], spread: float, wobble: float,
             window: int | None, order: int, jitter: float, drift: float, seed: int) -> Demonstrations:
    if not Interval(1.0, 10_000.0).contains(rate):
        raise ConfigError(out_of_range("tracker rate (Hz)", rate, Interval(1.0, 10_000.0)))
    if window is None:
        window = window_for_rate(rate, order)
    if duration * rate < max(window, order + 1):
        raise ConfigError(f"tracker recording of {duration} s at {rate} Hz is shorter than the "
                          f"derivative window ({window} samples)")
    for name, value, allowed in (("noise", noise, _AT_LEAST_0), ("jitter", jitter, _AT_LEAST_0),
                                 ("wobble", wobble, _AT_LEAST_0), ("drift", drift, _AT_LEAST_0),
                                 ("spread", spread, Interval(0, None, closed="neither")),
                                 ("n_recordings", n_recordings, Interval(1, None, type=int))):
        if not allowed.contains(value):
            raise ConfigError(out_of_range(f"tracker {name}", value, allowed))
    rng = np.random.default_rng(seed)
    rot = _tilt(rng, tilt_deg)
    origin = np.array([0.30, -0.05, 0.12])  # where the surface sits in the transmitter's frame (m)
    n = int(round(duration * rate))
    t_true = np.arange(n) / rate
    Xs, Ps, Ns, Ts = [], [], [], []
    for _ in range(n_recordings):  # loop over recordings (files), not samples
        seg = _tracker_segments(rng, duration, extent, speed, pause, aspect)
        ab, dab = _tracker_path(seg, t_true)
        ab[:, 1] *= spread
        dab[:, 1] *= spread
        if surface == "plane":
            x = origin + ab @ rot[:, :2].T
            pi = dab @ rot[:, :2].T
            normal = np.broadcast_to(rot[:, 2], x.shape)
        else:  # bowl: the inside of a sphere of ``radius``, bottom at the origin
            g = np.concatenate([ab, np.full((n, 1), -radius)], 1)
            gn = np.linalg.norm(g, axis=1, keepdims=True)
            d = g / gn
            dg = np.concatenate([dab, np.zeros((n, 1))], 1)
            dd = (dg - d * np.einsum("ni,ni->n", d, dg)[:, None]) / gn
            x = origin + (radius * (d + np.array([0, 0, 1.0]))) @ rot.T
            pi = (radius * dd) @ rot.T
            normal = d @ rot.T
        if wobble:  # the sensor rides on the finger: it rocks off the surface as the finger tilts
            x = x - _wobble(rng, t_true, wobble)[:, None] * normal
        Xs.append(x), Ps.append(pi), Ns.append(normal)
        # recorded-stamp errors, clipped so the stamps stay strictly increasing
        err = np.clip(rng.normal(scale=jitter, size=n), -0.45 / rate, 0.45 / rate) if jitter else 0.0
        Ts.append(t_true + err)
    X_true, pi, normal, t = (np.concatenate(a) for a in (Xs, Ps, Ns, Ts))
    demo = np.repeat(np.arange(n_recordings), n)
    X = X_true + rng.normal(scale=noise, size=X_true.shape) if noise else X_true.copy()
    if drift:
        X = X + drift * np.tile(t_true, n_recordings)[:, None] * unit_rows(rng.normal(size=(1, 3)))
    U = local_polynomial_derivative(t, X, demo, window, order)
    A = normal[:, None, :]
    if surface == "plane":
        truth = {"A": A[0], "N": nullspace_projection(A[:1])[0]}
    else:
        truth = {"A": A, "N": nullspace_projection(A)}
    truth.update(pi=pi, w=pi.copy(), v=np.zeros_like(pi), b=np.zeros((len(pi), 1)))
    meta = {"simulated": f"tracker_{surface}", "rate_hz": rate, "noise_m": noise,
            "derivative": {"window": window, "order": order}}
    return Demonstrations(X=X, U=U, demo=demo, t=t, truth=truth, state_names=["x", "y", "z"],
                          action_names=["dx/dt", "dy/dt", "dz/dt"], state_units=["m"] * 3,
                          action_units=["m/s"] * 3, metadata=meta, derivative=Derivative(True, window, order))


def tracker(
    surface: Literal["plane", "sphere"] = "plane",
    duration: float = 90.0,
    rate: float = 50.0,
    noise: float = 1e-3,
    n_recordings: int = 1,
    tilt_deg: float = 30.0,
    radius: float = 0.25,
    extent: float = 0.08,
    speed: tuple[float, float] = (0.03, 0.12),
    pause: tuple[float, float] = (0.5, 3.0),
    aspect: tuple[float, float] = (0.5, 1.0),
    spread: float = 1.0,
    wobble: float = 0.0,
    window: int | None = None,
    order: int = 2,
    jitter: float = 0.0,
    drift: float = 0.0,
    seed: int = 0,
) -> Demonstrations:
    """A finger with a Trakstar-style sensor tracing circles and figure-eights on a tilted
    ``surface``. ``plane`` (:func:`tracker_plane`): a table, one state-independent constraint,
    the plane's unit normal n (A = nᵀ, (1, 3)); ``sphere`` (:func:`tracker_sphere`): a bowl,
    see the end.

    Simulated (units: metres, seconds): ``n_recordings`` continuous recordings (one
    demonstration each, the way a tracker export arrives) of ``duration`` s sampled at
    ``rate`` Hz (50 by default; 50–500 Hz are realistic). The finger moves between random
    anchors within ``extent`` m of the middle in straight strokes and at each anchor traces an
    ellipse or a figure-eight (1–3 loops, radius 3–7 cm, aspect ratio uniform in ``aspect``);
    every stroke starts and ends at rest, mean speed per stroke uniform in ``speed`` m/s, and
    it pauses ``pause`` s after half the strokes (static stretches). ``spread`` < 1 squashes
    the whole drawing across one in-plane axis (a user who mostly wipes side to side: the
    actions then span the plane unevenly, a hard case for choosing the rank). The plane is
    tilted by ``tilt_deg`` about a seeded horizontal axis and sits at (0.30, −0.05, 0.12) m in
    the transmitter's frame.

    Observed: X (N, 3) positions with white noise of std ``noise`` m (default 1 mm; real
    sensors 0.2–2 mm), optionally a slow sensor drift of ``drift`` m/s along a seeded
    direction and a ``wobble`` (std, m) of the sensor off the surface as the finger rocks
    (five sines of 0.1–1 Hz along the normal); U (N, 3) the velocity the readers would derive
    from those positions (the same local polynomial, ``window`` samples, degree ``order``,
    io/derivative.py; by default the odd window spanning 0.16 s: 9 samples at 50 Hz — the
    readers' default — and 81 at 500 Hz, where 9 samples would leave velocities dominated by
    noise); stamps t (s) from 0 per recording, uniform at ``rate`` or with recorded-stamp
    errors of std ``jitter`` s (clipped to ±0.45 of a period).

    Truth: π (N, 3) the tangential velocity the user intends (the noise-free derivative of
    the path, so π = w = Nπ), v = 0, b = 0, A = nᵀ (1, 3) and N = I − nnᵀ (3, 3).

    ``sphere``: the same strokes traced inside a bowl, the inner
    surface of a sphere of ``radius`` m (one state-dependent constraint, the surface normal at
    x: A(x) = d(x)ᵀ with d the unit vector from the sphere's centre to the finger).

    The strokes are drawn in plane coordinates (a, b) (metres) and mapped to the bowl by the
    central projection x = c + R·(a, b, −R)/‖(a, b, −R)‖ (c the centre, R = ``radius``), so
    with the default ``extent`` the finger stays within ~35° of the bottom; the bowl is tilted
    by ``tilt_deg``. Observation model, units and truth as in :func:`tracker_plane`, except
    that A (N, 1, 3) and N (N, 3, 3) are per sample, at the noise-free position.
    """
    return _tracker(surface, duration=duration, rate=rate, noise=noise, n_recordings=n_recordings,
                    tilt_deg=tilt_deg, radius=0.0 if surface == "plane" else radius, extent=extent,
                    speed=speed, pause=pause, aspect=aspect, spread=spread, wobble=wobble, window=window,
                    order=order, jitter=jitter, drift=drift, seed=seed)


#: A finger on a tilted table (:func:`tracker` with ``surface="plane"``).
tracker_plane = partial(tracker, "plane")
#: A finger in a bowl of radius 0.25 m tilted by 15° (:func:`tracker` with ``surface="sphere"``).
tracker_sphere = partial(tracker, "sphere", tilt_deg=15.0)


def arm_at_rest(
    duration: float = 30.0,
    rate: float = 100.0,
    noise: float = 2e-3,
    position_noise: float = 1e-4,
    n_recordings: int = 1,
    seed: int = 0,
) -> Demonstrations:
    """A 7-DoF arm with a two-finger gripper recorded at rest (a data set with nothing to
    learn, for the diagnostics): joint_states positions (rad; fingers in m) and recorded
    velocities (rad/s, m/s) at ``rate`` Hz for ``duration`` s.

    The seven arm joints hold a seeded posture within ± half their limits; their positions
    carry white sensor noise of std ``position_noise`` rad and their velocities white noise
    of std ``noise`` rad/s. The two finger joints are constant (0.04 m, velocity 0). X, U
    (N, 9); no ground truth.
    """
    rng = np.random.default_rng(seed)
    half = np.deg2rad(SevenDofArm().limits_deg) / 2.0
    n = int(round(duration * rate))
    posture = np.r_[rng.uniform(-half, half), 0.04, 0.04]
    X = np.tile(posture, (n * n_recordings, 1))
    X[:, :7] += rng.normal(scale=position_noise, size=(len(X), 7))
    U = np.zeros_like(X)
    U[:, :7] = rng.normal(scale=noise, size=(len(X), 7))
    names = [f"lwr_arm_{i}_joint" for i in range(7)] + ["finger_joint_1", "finger_joint_2"]
    return Demonstrations(X=X, U=U, demo=np.repeat(np.arange(n_recordings), n),
                          t=np.tile(np.arange(n) / rate, n_recordings), state_names=names,
                          action_names=[f"d{k}/dt" for k in names], state_units=["rad"] * 7 + ["m"] * 2,
                          action_units=["rad/s"] * 7 + ["m/s"] * 2, metadata={"simulated": "arm_at_rest"})
