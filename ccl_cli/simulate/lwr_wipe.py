"""A KUKA LWR 4+ wiping a table, logged as researchers save it from MATLAB.

The arm is the LWR 4+ chain of :data:`ccl_cli.learn.robots.LWR4` (published DH table, flange
frame) driven by :func:`ccl_cli.simulate.wipe.wipe_log`: approach (free) → wipe (on a tilted
table, A = nᵀ in task space, A(q) = nᵀJ_p(q) in joint space) → retract (free).

:func:`proc_data` resamples each demonstration at its own sampling interval (0.0097–0.0135 s,
as a real-time loop that missed its period) into MATLAB's layout, one sample per column:

* ``X`` (13, T): flange position (m), unit quaternion (w, x, y, z), force (N), torque (N m);
* ``J`` (7, T): joint angles (rad);
* ``dt``: the demonstration's sampling interval (s).

A list of these dicts saved with ``scipy.io.savemat({"proc_data": cells})`` (cells an object
array (1, D)) is the ``proc_data`` 1×D cell array of structs.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.learn.robots import LWR4, quaternions
from ccl_cli.simulate.wipe import ChainArm, WipeLog, wipe_log

#: the comfortable posture (rad) the LWR wipes around: shoulder forward, elbow bent, flange down
POSTURE = np.array([0.0, 0.6, 0.0, -1.6, 0.0, 0.9, 0.0])
#: range of the per-demonstration sampling intervals (s)
INTERVALS = (0.0097, 0.0135)


def lwr_wipe_log(n_demos: int = 6, seed: int = 0, **options: Any) -> WipeLog:
    """:func:`~ccl_cli.simulate.wipe.wipe_log` of the LWR 4+ around :data:`POSTURE` at 200 Hz;
    ``options`` pass on (force, bias, noise levels, ...)."""
    options.setdefault("rate", 200.0)
    return wipe_log(n_demos=n_demos, seed=seed, arm=ChainArm(LWR4.chain()), posture=POSTURE, **options)


def proc_data(log: WipeLog, seed: int = 0, intervals: tuple[float, float] = INTERVALS
              ) -> list[dict[str, Any]]:
    """Per demonstration of ``log``: ``{"X": (13, T), "J": (7, T), "dt": float}`` resampled
    (linear interpolation of the logged joints and wrench) every ``dt`` s, dt drawn uniformly
    in ``intervals``; X's pose is the flange's forward kinematics of the resampled joints."""
    rng = np.random.default_rng(seed)
    chain = LWR4.chain()
    out = []
    for d in np.unique(log.demo):  # a loop over demonstrations; each step batched over samples
        rows = log.demo == d
        t = log.t[rows]
        dt = float(rng.uniform(*intervals))
        ts = np.arange(0.0, t[-1], dt)
        q = _resample(ts, t, log.q[rows])
        wrench = _resample(ts, t, log.wrench[rows])
        pose = chain.forward(q)
        quat = quaternions(pose.rotation)
        X = np.hstack([pose.position, quat, wrench])
        out.append({"X": X.T, "J": q.T, "dt": dt})
    return out


def wipe_ranges(log: WipeLog) -> dict[int, list[list[float]]]:
    """The labelled wipe phase of each demonstration, ``{index: [[start, end]]}`` in seconds
    from its first sample (as ``demos.ranges`` takes them)."""
    return {d: [[float(a), float(b)] for a, b in [phases["wipe"]]]
            for d, phases in enumerate(log.metadata["phases"])}


def _resample(ts: np.ndarray, t: np.ndarray, values: np.ndarray) -> np.ndarray:
    """Columns of ``values`` (n, d) at times t (n,) linearly interpolated at ts (m,) → (m, d)."""
    return np.stack([np.interp(ts, t, values[:, j]) for j in range(values.shape[1])], 1)
