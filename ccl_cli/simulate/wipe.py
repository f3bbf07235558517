"""The 7-DoF arm wiping a plane: approach (free) → wipe (on the plane) → retract (free).

:func:`wipe_log` simulates what a robot logs — joint positions and velocities, end-effector
positions, a force/torque channel — and :func:`arm_wipe` / :func:`arm_wipe_joint` map it to
the task-space and joint-space :class:`~ccl_cli.dataset.Demonstrations` a reader would
produce from such a log.

The arm (:class:`~ccl_cli.learn.kinematics.SevenDofArm`) follows an end-effector path by
resolved rates, q̇ = J_p⁺ ẋ_d + (I − J_p⁺J_p) k (q* − q) (J_p the (3, 7) position rows of the
Jacobian, q* a comfortable posture), integrated by RK4. While wiping, ẋ_d lies in the plane,
so the end-effector velocity along the plane's normal n is zero: in task space A = nᵀ
(1, 3); in joint space A(q) = nᵀJ_p(q) (1, 7). Approach and retract are free (N = I).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, Derivative
from ccl_cli.errors import ConfigError
from ccl_cli.learn.kinematics import SevenDofArm
from ccl_cli.learn.linalg import nullspace_projection, unit_rows
from ccl_cli.learn.robots import Chain
from ccl_cli.simulate.recordings import _sampled, derive, fault, stroke_phase
from ccl_cli.simulate.tracker import _tilt, _tracker_path, _tracker_segments

#: Phase codes of :attr:`WipeLog.phase`.
APPROACH, WIPE, RETRACT = 0, 1, 2
PHASES = ("approach", "wipe", "retract")
#: Gain (1/s) of the null-space pull towards the comfortable posture.
NULL_GAIN = 0.5
#: Smallest singular value (m/rad) of J_p allowed along a simulated path.
MIN_SINGULAR = 0.05
#: Rate (Hz) of the RK4 integration of the joint motion (the log is interpolated from it).
INTEGRATION_RATE = 100.0


@dataclass
class WipeLog:
    """What the robot logged, one sample per row (N samples, D demonstrations).

    t (N,) s from 0 per demonstration; demo (N,); phase (N,) APPROACH/WIPE/RETRACT;
    q, dq (N, 7) measured joint positions (rad) and velocities (rad/s); ee (N, 3) measured
    end-effector positions (m); wrench (N, 6) force (N) and torque (N m) in the base frame,
    with a constant bias; q_true, dq_true (N, 7), ee_true, ee_vel (N, 3) noise-free; normal
    (3,) the plane's unit normal; bias (6,); metadata: phases per demonstration, plane, rates.
    """

    t: np.ndarray
    demo: np.ndarray
    phase: np.ndarray
    q: np.ndarray
    dq: np.ndarray
    ee: np.ndarray
    wrench: np.ndarray
    q_true: np.ndarray
    dq_true: np.ndarray
    ee_true: np.ndarray
    ee_vel: np.ndarray
    normal: np.ndarray
    bias: np.ndarray
    metadata: dict[str, Any] = field(default_factory=dict)


@dataclass
class _Paths:
    """The desired end-effector path of every demonstration: approach from ``start`` to
    ``contact`` (D, 3), wipe ``strokes`` (one stroke script each, in the plane's axes E (3, 2)),
    retract by ``lift`` (D, 3); ``times`` (D, 4) the starts of the three phases and the end."""

    start: np.ndarray
    contact: np.ndarray
    lift: np.ndarray
    E: np.ndarray
    strokes: list[dict[str, np.ndarray]]
    times: np.ndarray
    normal: np.ndarray
    press: np.ndarray  # (D, 2, 3): frequencies (Hz) and phases of the pressing motion's sines
    compliance: float

    def pressing(self, tw: np.ndarray, demo: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """Offset δ (N,) along the normal while wiping and its rate δ̇: ``compliance`` × a sum of
        three sines (unit std) × a smooth 0.3-s ramp at each end of the wipe, so δ is 0 there."""
        dur = self.times[demo, 2] - self.times[demo, 1]
        f, ph = self.press[demo, 0], self.press[demo, 1]
        arg = 2 * np.pi * f * tw[:, None] + ph
        g, dg = np.sin(arg).sum(1) * np.sqrt(2 / 3), (2 * np.pi * f * np.cos(arg)).sum(1) * np.sqrt(2 / 3)
        s_in, s_out = np.clip(tw / 0.3, 0, 1), np.clip((dur - tw) / 0.3, 0, 1)
        h_in, h_out = s_in**2 * (3 - 2 * s_in), s_out**2 * (3 - 2 * s_out)
        ramp = h_in * h_out
        dramp = (6 * s_in * (1 - s_in) * h_out - h_in * 6 * s_out * (1 - s_out)) / 0.3
        return self.compliance * ramp * g, self.compliance * (dramp * g + ramp * dg)

    def desired(self, t: np.ndarray, demo: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """x_d (N, 3), ẋ_d (N, 3) and the phase (N,) at times t (N,) of demonstrations demo (N,)."""
        T = self.times[demo]
        phase = np.where(t < T[:, 1], APPROACH, np.where(t < T[:, 2], WIPE, RETRACT))
        tw = np.clip(t - T[:, 1], 0.0, T[:, 2] - T[:, 1])  # time into the wipe
        ab, dab = np.zeros((len(t), 2)), np.zeros((len(t), 2))
        for d, script in enumerate(self.strokes):  # one vectorised call per demonstration
            m = demo == d
            P, dP = _tracker_path(script, np.r_[0.0, tw[m]])
            ab[m], dab[m] = P[1:] - P[0], dP[1:]
        on_plane = self.contact[demo] + ab @ self.E.T
        delta, ddelta = self.pressing(tw, demo)
        wiping = (phase == WIPE)[:, None]
        x = on_plane + np.where(wiping, delta[:, None] * self.normal, 0.0)
        v = np.where(wiping, dab @ self.E.T + ddelta[:, None] * self.normal, 0.0)
        for p, i in ((APPROACH, 0), (RETRACT, 2)):
            m = phase == p
            dur = T[m, i + 1] - T[m, i]
            s, ds = stroke_phase((t[m] - T[m, i]) / dur)
            a = self.start[demo[m]] if p == APPROACH else on_plane[m]
            step = (self.contact[demo[m]] - a) if p == APPROACH else self.lift[demo[m]]
            x[m] = a + s[:, None] * step
            v[m] = (ds / dur)[:, None] * step
        return x, v, phase


class ChainArm:
    """A robot chain (:class:`~ccl_cli.learn.robots.Chain`, e.g. ``LWR4.chain()``) with the
    interface the wipe simulator drives: ``forward`` (N, n) → (N, 3), ``jacobian`` → (N, 6, n),
    ``limits_deg`` (n,) the smaller side of each joint's limits."""

    def __init__(self, chain: Chain) -> None:
        self.chain = chain
        self.name = chain.source
        self.n_joints = chain.n_joints
        self.limits_deg = np.rad2deg(np.minimum(-chain.lower, chain.upper))

    def forward(self, Q: np.ndarray) -> np.ndarray:
        return self.chain.forward(Q).position

    def jacobian(self, Q: np.ndarray) -> np.ndarray:
        return self.chain.jacobian(Q)


Arm = SevenDofArm | ChainArm


def _joint_rates(arm: Arm, q: np.ndarray, xdot: np.ndarray, target: np.ndarray) -> np.ndarray:
    """q̇ = J_p⁺ ẋ_d + (I − J_p⁺J_p) k (q* − q) for postures q (N, 7), desired ẋ_d (N, 3)."""
    J = arm.jacobian(q)[:, :3, :]
    Jp = J.transpose(0, 2, 1) @ np.linalg.inv(J @ J.transpose(0, 2, 1))  # J⁺ of a full-rank (3, 7) J
    null = np.eye(7) - Jp @ J
    return np.einsum("nij,nj->ni", Jp, xdot) + NULL_GAIN * np.einsum("nij,nj->ni", null, target - q)


def wipe_log(
    n_demos: int = 8,
    rate: float = 200.0,
    approach_s: tuple[float, float] = (1.0, 2.0),
    wipe_s: tuple[float, float] = (6.0, 9.0),
    retract_s: tuple[float, float] = (1.0, 2.0),
    height: tuple[float, float] = (0.08, 0.15),
    tilt_deg: float = 10.0,
    extent: float = 0.08,
    speed: tuple[float, float] = (0.05, 0.15),
    compliance: float = 1e-4,
    joint_noise: float = 2e-5,
    velocity_noise: float = 2e-3,
    ee_noise: float = 2e-5,
    force: tuple[float, float] = (5.0, 15.0),
    friction: float = 0.3,
    bias: float = 1.0,
    force_noise: float = 0.2,
    seed: int = 0,
    arm: Arm | None = None,
    posture: np.ndarray | None = None,
) -> WipeLog:
    """Simulate ``n_demos`` wipes of a table by the 7-DoF arm, logged at ``rate`` Hz.

    Per demonstration, from a posture near a seeded comfortable one q* (±10° per joint):
    *approach* ``approach_s`` s along a straight line (minimum-jerk, from rest to rest) down
    ``height`` m to the table; *wipe* ``wipe_s`` s of strokes, circles and figure-eights in the
    plane (the tracker's stroke script, :func:`~ccl_cli.simulate.tracker._tracker_segments`,
    mean speeds ``speed`` m/s, within ``extent`` m, ending at rest); *retract* ``retract_s`` s
    up ``height`` m and sideways. The table's normal is the vertical tilted by ``tilt_deg``
    about a seeded horizontal axis; the table lies ``height`` below the start. While wiping the
    tool presses into the compliant table and sponge: the end effector moves along n by
    ``compliance`` m (std; three sines of 0.2–2 Hz, zero at the ends of the wipe), so its
    velocity along n is small but not zero — A u = b with b = nᵀẋ small, as on a real table.

    Measured: q with white noise ``joint_noise`` rad; dq with white noise ``velocity_noise``
    rad/s (the robot's own velocity estimate); ee = FK(q) + white noise ``ee_noise`` m;
    wrench = bias + contact + white noise (``force_noise`` N, /20 N m for torques): the table
    pushes back along n with a force ramping in 0.15 s to a level in ``force`` N that varies by
    ±20 % at 0.5 Hz, friction ``friction`` × that force opposes the motion, torques are r × F
    for a tool tip 0.1 m below the sensor; the bias is constant, uniform in ±5·``bias`` N and
    ±0.3·``bias`` N m (the sensor was not zeroed).

    ``arm``: the 7-DoF arm (default :class:`~ccl_cli.learn.kinematics.SevenDofArm`; a
    :class:`ChainArm` for a robot model such as the LWR 4+); ``posture`` (7,) rad: the
    comfortable posture q* is drawn within ±10° of it (default: anywhere within 80 % of half the
    joint limits).
    """
    if n_demos < 1 or not 50.0 <= rate <= 1000.0:
        raise ConfigError(f"wipe_log needs n_demos ≥ 1 and a rate in [50, 1000] Hz, got {n_demos}, {rate}")
    rng = np.random.default_rng(seed)
    arm = arm or SevenDofArm()
    half = np.deg2rad(arm.limits_deg) / 2
    normal = _tilt(rng, tilt_deg)[:, 2]
    e1 = unit_rows(np.cross(normal, rng.normal(size=3))[None])[0]
    E = np.stack([e1, np.cross(normal, e1)], 1)  # (3, 2) in-plane axes
    for _attempt in range(50):  # postures until the arm stays clear of singularities and limits
        target = rng.uniform(-half, half) * 0.8 if posture is None else \
            np.asarray(posture, float) + np.deg2rad(rng.uniform(-10, 10, 7))
        q0 = target + np.deg2rad(rng.uniform(-10, 10, (n_demos, 7)))
        log = _integrate(arm, rng, q0, target, normal, E, rate, approach_s, wipe_s, retract_s, height,
                         extent, speed, compliance)
        if log is not None:
            break
    else:
        raise ConfigError("no posture kept the arm clear of singularities: try another seed")
    q_true, dq_true, ee_vel, phase, t, demo, times, plane_point = log
    ee_true = arm.forward(q_true)
    q = q_true + rng.normal(scale=joint_noise, size=q_true.shape) if joint_noise else q_true.copy()
    dq = dq_true + rng.normal(scale=velocity_noise, size=q.shape) if velocity_noise else dq_true.copy()
    ee = arm.forward(q) + (rng.normal(scale=ee_noise, size=ee_true.shape) if ee_noise else 0.0)
    level = rng.uniform(*force, n_demos)[demo] * (1 + 0.2 * np.sin(np.pi * t + rng.uniform(0, 2 * np.pi)))
    tw = np.stack([t - times[demo, 1], times[demo, 2] - t], 1).min(1)  # time inside the wipe
    ramp = 0.5 * (1 - np.cos(np.pi * np.clip(tw / 0.15, 0.0, 1.0)))
    speed_n = np.linalg.norm(ee_vel, axis=1, keepdims=True)
    F = (level * ramp)[:, None] * (normal - friction * ee_vel / np.maximum(speed_n, 1e-3))
    F[phase != WIPE] = 0.0
    tau = np.cross(-0.1 * normal, F)
    b = np.r_[rng.uniform(-5, 5, 3), rng.uniform(-0.3, 0.3, 3)] * bias
    noise6 = np.r_[[force_noise] * 3, [force_noise / 20] * 3]
    wrench = b + np.c_[F, tau] + rng.normal(size=(len(t), 6)) * noise6
    phases = [{name: [float(times[d, i]), float(times[d, i + 1])] for i, name in enumerate(PHASES)}
              for d in range(n_demos)]
    meta = {"rate_hz": rate, "phases": phases, "normal": normal.tolist(), "plane_point": plane_point.tolist(),
            "comfortable_posture_rad": target.tolist(), "noise": {"joint_rad": joint_noise,
            "velocity_rad_s": velocity_noise, "ee_m": ee_noise, "force_N": force_noise},
            "force": {"bias": b.tolist(), "frame": "base", "units": ["N"] * 3 + ["N m"] * 3}}
    return WipeLog(t=t, demo=demo, phase=phase, q=q, dq=dq, ee=ee, wrench=wrench, q_true=q_true,
                   dq_true=dq_true, ee_true=ee_true, ee_vel=ee_vel, normal=normal, bias=b, metadata=meta)


def _integrate(arm: Arm, rng: np.random.Generator, q0: np.ndarray, target: np.ndarray,
               normal: np.ndarray, E: np.ndarray, rate: float, approach_s: tuple[float, float],
               wipe_s: tuple[float, float], retract_s: tuple[float, float], height: tuple[float, float],
               extent: float, speed: tuple[float, float], compliance: float) -> tuple | None:
    """Draw the paths and integrate the joint motion by RK4 at INTEGRATION_RATE; the logged
    postures are cubic Hermite interpolants of the steps and the logged velocities the rate law
    at them (so a wiping sample's velocity is exactly in the plane). None when the arm comes
    within MIN_SINGULAR of a singularity or leaves its joint limits."""
    n_demos = len(q0)
    start = arm.forward(q0)
    plane_point = start.mean(0) - normal * rng.uniform(*height)
    contact = (start - ((start - plane_point) @ normal)[:, None] * normal
               + rng.uniform(-0.03, 0.03, (n_demos, 2)) @ E.T)
    strokes = [_tracker_segments(rng, rng.uniform(*wipe_s), extent, speed, (0.2, 0.8), (0.5, 1.0))
               for _ in range(n_demos)]
    wipe_dur = np.array([s["start"][-1] + s["dur"][-1] for s in strokes])  # the last stroke ends at rest
    durations = np.stack([rng.uniform(*approach_s, n_demos), wipe_dur, rng.uniform(*retract_s, n_demos)], 1)
    lift = normal * rng.uniform(*height, (n_demos, 1)) + rng.uniform(-0.05, 0.05, (n_demos, 2)) @ E.T
    press = np.stack([rng.uniform(0.2, 2.0, (n_demos, 3)), rng.uniform(0, 2 * np.pi, (n_demos, 3))], 1)
    paths = _Paths(start, contact, lift, E, strokes, np.c_[np.zeros(n_demos), np.cumsum(durations, 1)],
                   normal, press, compliance)
    dt = 1.0 / INTEGRATION_RATE
    n_steps = int(np.ceil(paths.times[:, -1].max() / dt)) + 1
    half = np.arange(2 * n_steps + 1) * dt / 2  # every time RK4 evaluates the rate law at
    _, vd, _ = paths.desired(np.tile(half, n_demos), np.repeat(np.arange(n_demos), len(half)))
    vd = vd.reshape(n_demos, len(half), 3)
    Q, F = np.empty((n_demos, n_steps + 1, 7)), np.empty((n_demos, n_steps + 1, 7))
    q = q0.copy()
    for i in range(n_steps + 1):  # time steps, batched over demonstrations
        k1 = _joint_rates(arm, q, vd[:, 2 * i], target)
        Q[:, i], F[:, i] = q, k1
        if i == n_steps:
            break
        k2 = _joint_rates(arm, q + dt / 2 * k1, vd[:, 2 * i + 1], target)
        k3 = _joint_rates(arm, q + dt / 2 * k2, vd[:, 2 * i + 1], target)
        k4 = _joint_rates(arm, q + dt * k3, vd[:, 2 * i + 2], target)
        q = q + dt / 6 * (k1 + 2 * k2 + 2 * k3 + k4)
    t, demo = _sampled(paths.times[:, -1], rate)
    i = np.minimum((t / dt).astype(int), n_steps - 1)
    s = (t / dt - i)[:, None]
    h00, h10, h01, h11 = 2 * s**3 - 3 * s**2 + 1, s**3 - 2 * s**2 + s, -2 * s**3 + 3 * s**2, s**3 - s**2
    q_log = h00 * Q[demo, i] + h10 * dt * F[demo, i] + h01 * Q[demo, i + 1] + h11 * dt * F[demo, i + 1]
    x_d, v_d, phase = paths.desired(t, demo)
    dq_log = _joint_rates(arm, q_log, v_d, target)
    sv = np.linalg.svd(arm.jacobian(q_log)[:, :3, :], compute_uv=False)[:, -1]
    if sv.min() < MIN_SINGULAR or np.any(np.abs(q_log) > np.deg2rad(arm.limits_deg)):
        return None
    return q_log, dq_log, v_d, phase, t, demo, paths.times, plane_point


def _wipe_data(log: WipeLog, X: np.ndarray, U: np.ndarray, truth: dict[str, np.ndarray], space: str,
               names: list[str], units: list[str], derivative: dict[str, int] | None) -> Demonstrations:
    bias = fault("force_bias", [], log.t, value=log.bias.tolist(), channel="wrench")
    bias.update(count=int(np.any(log.bias != 0)))
    meta = {"simulated": f"arm_wipe_{space}", **log.metadata, "faults": [bias]}
    if derivative:
        meta["derivative"] = derivative
    return Demonstrations(X=X, U=U, demo=log.demo, t=log.t, truth=truth, state_names=names,
                          action_names=[f"d{n}/dt" for n in names], state_units=units,
                          action_units=[f"{u}/s" for u in units], metadata=meta,
                          derivative=Derivative.of(derivative) if derivative else Derivative())


def _split(N: np.ndarray, velocity: np.ndarray) -> dict[str, np.ndarray]:
    """Ground truth of true velocities (N, q) under projections N (N, q, q): w = π = N u, v = u − w."""
    w = np.einsum("nij,nj->ni", N, velocity)
    return {"N": N, "pi": w, "w": w.copy(), "v": velocity - w}


def arm_wipe(n_demos: int = 8, rate: float = 200.0, noise: float = 2e-5, tilt_deg: float = 10.0,
             compliance: float = 1e-4, offset: float = 0.0, drift: float = 0.0, seed: int = 0,
             force: bool = False) -> Demonstrations:
    """Task space of :func:`wipe_log`: X the measured end-effector positions (N, 3) (FK of the
    measured joints plus white noise of std ``noise`` m), U their velocities derived as the
    readers do (N, 3).

    Sensor bias: the positions are off by ``offset`` m (a constant, seeded direction: a
    calibration error) plus ``drift`` m/s × t along another seeded direction (a position sensor
    that drifts), so the derived velocities carry a constant bias of ``drift`` m/s.

    Truth: N = I − nnᵀ while wiping and I in approach and retract (N, 3, 3); of the noise-free
    end-effector velocity u, w = π = N u and v = u − w (the pressing motion along n while
    wiping, ``compliance``). A is not stored (its row count changes with the phase);
    ``metadata["phases"]`` gives each demonstration's phase times, ``metadata["normal"]`` n.

    ``force``: the dataset carries the force/torque channel's force (N, 3) in the base frame
    (:attr:`~ccl_cli.dataset.Demonstrations.force`: bias, contact with friction, noise)."""
    log = wipe_log(n_demos=n_demos, rate=rate, ee_noise=noise, tilt_deg=tilt_deg, compliance=compliance,
                   seed=seed)
    ee = log.ee
    if offset or drift:
        way = unit_rows(np.random.default_rng([seed, 1]).normal(size=(2, 3)))
        ee = ee + offset * way[0] + drift * log.t[:, None] * way[1]
    U, deriv = derive(log.t, ee, log.demo, rate)
    wiping = (log.phase == WIPE)[:, None, None]
    N = np.where(wiping, np.eye(3) - np.outer(log.normal, log.normal), np.eye(3))
    d = _wipe_data(log, ee, U, _split(N, log.ee_vel), "task", ["x", "y", "z"], ["m"] * 3, deriv)
    if force:
        d.force = log.wrench[:, :3].copy()
    if offset or drift:
        d.metadata["position_bias"] = {"offset_m": offset, "offset_direction": way[0].tolist(),
                                       "drift_m_s": drift, "drift_direction": way[1].tolist()}
    return d


def arm_wipe_joint(n_demos: int = 8, rate: float = 200.0, noise: float = 2e-3, tilt_deg: float = 10.0,
                   compliance: float = 1e-4, seed: int = 0) -> Demonstrations:
    """Joint space of :func:`wipe_log`: X the measured joint positions (N, 7), U the robot's
    recorded joint velocities (N, 7) with white noise of std ``noise`` rad/s.

    Truth: N = I − A⁺A with A(q) = nᵀJ_p(q) (1, 7) while wiping, I in approach and retract
    (N, 7, 7); of the noise-free joint velocity u, w = π = N u and v = u − w = A⁺b."""
    log = wipe_log(n_demos=n_demos, rate=rate, velocity_noise=noise, tilt_deg=tilt_deg, compliance=compliance,
                   seed=seed)
    A = np.einsum("i,nij->nj", log.normal, SevenDofArm().jacobian(log.q_true)[:, :3, :])[:, None, :]
    N = np.where((log.phase == WIPE)[:, None, None], nullspace_projection(A), np.eye(7))
    return _wipe_data(log, log.q, log.dq, _split(N, log.dq_true), "joint", [f"q{i + 1}" for i in range(7)],
                      ["rad"] * 7, None)


def phase_subset(d: Demonstrations, phase: str) -> Demonstrations:
    """The samples of each demonstration of an :func:`arm_wipe` / :func:`arm_wipe_joint` recording
    inside its ``phase`` ("approach", "wipe" or "retract"; ``metadata["phases"]``)."""
    keep = np.zeros(d.n_samples, bool)
    for i, p in enumerate(d.metadata["phases"]):
        t0, t1 = p[phase]
        keep |= (d.demo == i) & (d.t >= t0) & (d.t < t1)
    return d.subset(keep)
