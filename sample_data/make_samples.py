"""Regenerate the shipped sample data (run from the repository root):

    python sample_data/make_samples.py

Simulated problems are written with ``ccl simulate``'s library function and the
canonical HDF5 writer; the "real format" samples are written by the third-party
writers: a Trakstar-style CSV export (csv module) of a finger sliding on a tilted
plane at 50 Hz, one continuous 60-s recording of a finger in a bowl (CSV), and a ROS 1
bag (rosbags) of a 7-DoF KUKA-like arm publishing sensor_msgs/JointState at 100 Hz while its
end-effector height is held fixed, and a KUKA LWR 4+ wiping log as researchers save it from
MATLAB (scipy.io.savemat, v5: ``proc_data``, a 1×6 cell of structs with X 13×T, J 7×T, dt) with
the LWR's URDF written from its DH table.
"""

from __future__ import annotations

import csv
from pathlib import Path

import numpy as np

from ccl_cli import simulate as sim
from ccl_cli.io import write_demonstrations
from ccl_cli.learn.kinematics import SevenDofArm
from ccl_cli.learn.linalg import nullspace_projection

HERE = Path(__file__).resolve().parent
EPOCH_NS = 1_700_000_000_000_000_000


def simulated() -> None:
    sets = {
        "toy2d_ncl.h5": sim.toy2d(constraint="fixed", task=True, sampling="uniform", n_samples=1000,
                                  n_demos=10, seed=0),
        "toy2d_parabola.h5": sim.toy2d(constraint="parabola", seed=0),
        "varying_constraint.h5": sim.varying_constraint(task=True, noise=0.01, seed=0),
        "two_link.h5": sim.two_link(seed=0),
        "arm7.h5": sim.arm7(rows=(0, 1), seed=0),
    }
    for name, data in sets.items():
        write_demonstrations(HERE / name, data, time_origin_ns=EPOCH_NS,
                             provenance={"made_by": "sample_data/make_samples.py"}, force=True)


def trakstar_csv(path: Path, n_demos: int = 6, rate: float = 50.0, seconds: float = 4.0) -> None:
    """Finger on the plane n·x = 0 (n = unit(0.2, −0.3, 1)); each stroke a smooth curve
    in the plane; 0.2 s gaps between strokes; position noise 0.1 mm."""
    rng = np.random.default_rng(0)
    normal = np.array([0.2, -0.3, 1.0])
    normal /= np.linalg.norm(normal)
    e1 = np.cross(normal, [0, 0, 1.0])
    e1 /= np.linalg.norm(e1)
    e2 = np.cross(normal, e1)
    rows, t0 = [], EPOCH_NS
    for _ in range(n_demos):
        t = np.arange(0, seconds, 1 / rate)
        a, b, w1, w2 = rng.uniform(0.05, 0.15, 2).tolist() + rng.uniform(0.5, 2.0, 2).tolist()
        p = np.outer(a * np.sin(w1 * t + rng.uniform(0, 6)), e1) + np.outer(b * np.cos(w2 * t), e2)
        p += rng.normal(scale=1e-4, size=p.shape)
        q = np.tile([0.0, 0.0, 0.0, 1.0], (len(t), 1))  # sensor orientation (unused)
        stamps = t0 + np.round(t * 1e9).astype(np.int64)
        rows += [[int(s), *map(float, pi), *map(float, qi)] for s, pi, qi in zip(stamps, p, q, strict=True)]
        t0 = int(stamps[-1]) + 200_000_000
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["%time", "x", "y", "z", "x", "y", "z", "w"])  # as a rosbag→CSV export
        w.writerows(rows)


def trakstar_bowl_csv(path: Path, seconds: float = 60.0) -> None:
    """One continuous recording (``ccl simulate tracker_sphere``): a finger tracing circles and
    figure-eights inside a bowl (sphere of radius 0.25 m), 50 Hz, position noise 1 mm, pauses
    and varying speed; positions written in metres to the micrometre, as a tracker exports."""
    data = sim.tracker_sphere(duration=seconds, rate=50.0, noise=1e-3, seed=0)
    stamps = EPOCH_NS + np.round(data.t * 1e9).astype(np.int64)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["%time", "x", "y", "z"])
        w.writerows([[int(s), *(f"{v:.6f}" for v in x)] for s, x in zip(stamps, data.X, strict=True)])


def kuka_bag(path: Path, n_demos: int = 4, rate: float = 100.0, seconds: float = 3.0) -> None:
    """JointState of the 7-DoF chain moving with π = q* − q under A(q) = J_z(q)
    (end-effector height held), positions and velocities, joints published in a
    shuffled order per message (as some drivers do)."""
    from rosbags.rosbag1 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC)
    JointState = ts.types["sensor_msgs/msg/JointState"]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    arm = SevenDofArm()
    rng = np.random.default_rng(1)
    half = np.deg2rad(arm.limits_deg) / 2
    names = [f"lwr_arm_{i}_joint" for i in range(7)]
    with Writer(path) as writer:
        conn = writer.add_connection("/joint_states", "sensor_msgs/msg/JointState", typestore=ts)
        t_ns, seq = EPOCH_NS, 0
        for _ in range(n_demos):
            q = rng.uniform(-half, half)
            target = rng.uniform(-half, half)
            for _ in range(int(seconds * rate)):
                A = arm.jacobian(q[None])[:, 2:3, :]
                u = (nullspace_projection(A) @ (target - q)[:, None, None].reshape(1, 7, 1))[0, :, 0]
                order = rng.permutation(7)
                sec, nsec = divmod(t_ns, 1_000_000_000)
                msg = JointState(header=Header(seq=seq, stamp=Time(sec=sec, nanosec=nsec), frame_id=""),
                                 name=[names[k] for k in order], position=q[order].copy(),
                                 velocity=u[order] + rng.normal(scale=1e-3, size=7), effort=np.zeros(7))
                writer.write(conn, t_ns + 2_000_000, ts.serialize_ros1(msg, "sensor_msgs/msg/JointState"))
                q = q + u / rate
                t_ns += int(1e9 / rate)
                seq += 1
            t_ns += 1_000_000_000  # one second between demonstrations


def lwr_wipe_mat(path: Path, urdf: Path, n_demos: int = 6) -> dict[int, list[list[float]]]:
    """The LWR 4+ wiping a tilted table (approach → wipe → retract; :mod:`ccl_cli.simulate.lwr_wipe`),
    each demonstration at its own sampling interval (0.0097–0.0135 s); returns the labelled wipe
    phases (``demos.ranges``, seconds from each demonstration's start)."""
    import scipy.io

    from ccl_cli.learn.robots import LWR4
    from ccl_cli.simulate.lwr_wipe import lwr_wipe_log, proc_data, wipe_ranges

    log = lwr_wipe_log(n_demos=n_demos, seed=0, wipe_s=(3.0, 5.0), force=(8.0, 15.0), bias=0.3)
    cells = np.empty((1, n_demos), dtype=object)
    for k, cell in enumerate(proc_data(log, seed=0)):
        cells[0, k] = cell
    scipy.io.savemat(path, {"proc_data": cells}, do_compression=True)
    urdf.write_text(LWR4.urdf())
    return wipe_ranges(log)


if __name__ == "__main__":
    simulated()
    trakstar_csv(HERE / "trakstar_plane.csv")
    trakstar_bowl_csv(HERE / "trakstar_bowl.csv")
    (HERE / "kuka_wipe.bag").unlink(missing_ok=True)
    kuka_bag(HERE / "kuka_wipe.bag")
    for k, span in lwr_wipe_mat(HERE / "lwr_wipe.mat", HERE / "lwr4.urdf").items():
        print(f"lwr_wipe.mat demo {k}: wipe {span}")
    for p in sorted(HERE.iterdir()):
        if p.suffix in (".h5", ".csv", ".bag", ".mat"):
            print(f"{p.name:28s} {p.stat().st_size / 1024:8.1f} KiB")
