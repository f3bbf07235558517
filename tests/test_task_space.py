"""Task space from joint logs: ``state: {..., forward_kinematics: {robot, frame, orientation}}``.

Logs are written at test time by the csv module and rosbags (tests/writers.py); the robot is the
KUKA LWR 4+ as a URDF written from its published DH table. Positions are checked against an
independent standard-DH product written here, velocities v = J_p(q) q̇ against the time
derivative of those positions along a smooth joint trajectory.
"""

import csv

import numpy as np
import pytest
from writers import JOINTS, joint_recording, write_ros2_bag

from ccl_cli.errors import InputError
from ccl_cli.io import load_demonstrations
from ccl_cli.learn.robots import LWR4

LWR_NAMES = [f"a{i}" for i in range(1, 8)]


def dh_positions(Q: np.ndarray) -> np.ndarray:
    """Flange positions (N, 3) of the LWR 4+ by the standard DH product, written independently:
    T_i = Rot_z(θ_i) Trans_z(d_i) Trans_x(a_i) Rot_x(α_i)."""
    out = np.empty((len(Q), 3))
    for n, q in enumerate(Q):  # a reference implementation: clarity over speed
        T = np.eye(4)
        for (a, d, alpha, theta0), th in zip(LWR4.table, q, strict=True):
            ct, st, ca, sa = np.cos(th + theta0), np.sin(th + theta0), np.cos(alpha), np.sin(alpha)
            T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                              [0, sa, ca, d], [0, 0, 0, 1]])
        out[n] = T[:3, 3]
    return out


def smooth_joints(t: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """q(t) (N, 7) and q̇(t) around a bent posture."""
    k = np.arange(1, 8)
    q = np.array([0.0, 0.6, 0.0, -1.6, 0.0, 0.9, 0.0]) + 0.3 * np.sin(0.5 * k * t[:, None] + k)
    dq = 0.3 * 0.5 * k * np.cos(0.5 * k * t[:, None] + k)
    return q, dq


def write_joint_csv(path, t, q, dq, names):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", *names, *(f"v_{n}" for n in names)])
        w.writerows([[repr(float(a)), *map(repr, qi.tolist()), *map(repr, vi.tolist())]
                     for a, qi, vi in zip(t, q, dq, strict=True)])
    return path


@pytest.fixture
def lwr_urdf(tmp_path):
    path = tmp_path / "lwr.urdf"
    path.write_text(LWR4.urdf())
    return path


def test_csv_joints_to_flange_positions_and_velocities_by_name(tmp_path, lwr_urdf):
    t = np.arange(400) / 200.0
    q, dq = smooth_joints(t)
    order = [3, 0, 6, 1, 5, 2, 4]  # columns in another order, names with a driver's prefix
    names = [f"lwr_{LWR_NAMES[k]}" for k in order]
    path = write_joint_csv(tmp_path / "joints.csv", t, q[:, order], dq[:, order], names)
    fk = {"robot": str(lwr_urdf), "frame": "flange"}
    cfg = {"files": [str(path)], "time": {"column": "time"},
           "state": {"columns": names, "forward_kinematics": fk},
           "action": {"columns": [f"v_{n}" for n in names]}}
    data = load_demonstrations(cfg)
    assert data.state_names == ["x", "y", "z"] and data.state_units == ["m"] * 3
    np.testing.assert_allclose(data.X, dh_positions(q), atol=1e-12)
    # v = J_p(q) q̇ equals d/dt of the positions (central differences, O(h²) at h = 1e-5 s)
    h = 1e-5
    fd = (dh_positions(smooth_joints(t + h)[0]) - dh_positions(smooth_joints(t - h)[0])) / (2 * h)
    np.testing.assert_allclose(data.U, fd, atol=1e-7)
    # derived from the positions instead (no action): close to the same velocities
    derived = load_demonstrations({k: v for k, v in cfg.items() if k != "action"})
    np.testing.assert_allclose(derived.U[5:-5], fd[5:-5], atol=2e-3)
    # with orientation: unit quaternions, one hemisphere along the log
    oriented = {"columns": names, "forward_kinematics": {**fk, "orientation": True}}
    both = load_demonstrations({**cfg, "action": None, "state": oriented})
    assert both.state_names == ["x", "y", "z", "qw", "qx", "qy", "qz"]
    quat = both.X[:, 3:]
    np.testing.assert_allclose(np.linalg.norm(quat, axis=1), 1.0, atol=1e-12)
    assert (np.einsum("ij,ij->i", quat[1:], quat[:-1]) > 0).all()


def test_joint_names_that_do_not_match_are_one_clear_line(tmp_path, lwr_urdf):
    t = np.arange(50) / 100.0
    q, dq = smooth_joints(t)
    names = LWR_NAMES[:6] + ["gripper"]
    path = write_joint_csv(tmp_path / "joints.csv", t, q, dq, names)
    cfg = {"files": [str(path)], "time": {"column": "time"},
           "state": {"columns": names, "forward_kinematics": {"robot": str(lwr_urdf)}}}
    with pytest.raises(InputError, match=r"joints.csv: state.forward_kinematics: joint names do not match: "
                                         r"joints of .* missing from the log: a7; "
                                         r"log joints not in .*: gripper"):
        load_demonstrations(cfg)
    with pytest.raises(InputError, match="no_such.urdf"):
        missing = {"columns": names, "forward_kinematics": {"robot": "no_such.urdf"}}
        load_demonstrations({**cfg, "state": missing})


def test_jointstate_bag_names_matched_to_a_dh_robot(tmp_path):
    rec = joint_recording(n=60, rate=100.0, shuffle=True)
    path = write_ros2_bag(tmp_path / "b", rec)
    dh = {"dh": [list(row) for row in LWR4.table], "names": JOINTS}
    cfg = {"files": [str(path)], "state": {"topic": "/joint_states", "field": "position",
                                           "forward_kinematics": {"robot": dh}}}
    data = load_demonstrations(cfg)
    np.testing.assert_allclose(data.X, dh_positions(rec.position), atol=1e-12)
    assert data.metadata["files"][0]["forward_kinematics"]["joints"] == JOINTS
    # the robot's names with a driver's prefix in the log: matched through the joints given
    short = {"dh": [list(row) for row in LWR4.table], "names": [str(i) for i in range(1, 8)]}
    state = {**cfg["state"], "joints": JOINTS[::-1], "forward_kinematics": {"robot": short}}
    action = {"topic": "/joint_states", "field": "velocity"}  # read in the state's joint order
    named = load_demonstrations({**cfg, "state": state, "action": action})
    np.testing.assert_allclose(named.X, data.X, atol=1e-12)
    J = LWR4.chain().jacobian(rec.position, rows=[0, 1, 2])
    np.testing.assert_allclose(named.U, np.einsum("nij,nj->ni", J, rec.velocity), atol=1e-12)
    bad = {"dh": [list(row) for row in LWR4.table], "names": LWR_NAMES}
    with pytest.raises(InputError, match=r"joint\(s\) a1, a2, a3, a4, a5, a6, a7 not in /joint_states"):
        load_demonstrations({**cfg, "state": {**cfg["state"], "forward_kinematics": {"robot": bad}}})
    with pytest.raises(InputError, match="missing from the log: 1, 2, 3, 4, 5, 6, 8; log joints not in"):
        other = {**short, "names": [*short["names"][:6], "8"]}
        state = {**cfg["state"], "joints": JOINTS, "forward_kinematics": {"robot": other}}
        load_demonstrations({**cfg, "state": state})


def test_bag_joints_forward_kinematics_cut_where_a_force_topic_is_high(tmp_path):
    rec = joint_recording(n=300, rate=100.0)
    t_f = rec.t_ns[::2]  # a 50 Hz force topic (log time: no header)
    force = np.zeros((len(t_f), 3))
    force[20:60, 2] = 12.0  # contact 0.4–1.18 s
    force[100:103, 0] = 9.0  # a 0.04-s brush
    path = write_ros2_bag(tmp_path / "w", rec, extra=("/force", t_f, force))
    dh = {"dh": [list(row) for row in LWR4.table], "names": JOINTS}
    cfg = {"files": [str(path)], "state": {"topic": "/joint_states", "field": "position",
                                           "forward_kinematics": {"robot": dh}},
           "action": {"topic": "/joint_states", "field": "velocity"},
           "demos": {"where": {"topic": "/force", "norm_above": 5.0}, "min_duration": 0.2}}
    data = load_demonstrations(cfg)
    assert data.n_demos == 1
    # the force norm linearly interpolated onto the joint stamps: above 5 N from the midpoint
    # before the first contact sample to the midpoint after the last (81 samples)
    level = np.interp((rec.t_ns - t_f[0]).astype(float), (t_f - t_f[0]).astype(float), force[:, 2])
    inside = level > 5.0
    assert inside.sum() == 81
    np.testing.assert_allclose(data.X, dh_positions(rec.position[inside]), atol=1e-12)
    J = LWR4.chain().jacobian(rec.position[inside], rows=[0, 1, 2])
    np.testing.assert_allclose(data.U, np.einsum("nij,nj->ni", J, rec.velocity[inside]), atol=1e-12)
    assert data.action_names == ["vx", "vy", "vz"]


def test_hdf5_layout_joint_names_forward_kinematics_and_ranges_per_demo(tmp_path, lwr_urdf):
    import h5py

    path = tmp_path / "robo.h5"
    names = [f"arm/{n}" for n in LWR_NAMES[::-1]]  # reversed, with a namespace
    t = np.arange(300) / 100.0
    with h5py.File(path, "w") as f:  # a robomimic-like layout: data/demo_K/obs/joint_pos, joint_vel, t
        for k in range(2):
            q, dq = smooth_joints(t + k)
            g = f.create_group(f"data/demo_{k}")
            g.create_dataset("obs/joint_pos", data=q[:, ::-1]).attrs["names"] = names
            g.create_dataset("obs/joint_vel", data=dq[:, ::-1])
            g.create_dataset("t", data=t)
    fk = {"robot": str(lwr_urdf)}
    cfg = {"files": [str(path)], "state": {"dataset": "obs/joint_pos", "forward_kinematics": fk},
           "action": {"dataset": "obs/joint_vel"}, "time": {"dataset": "t"},
           "demos": {"group": "data/demo_*", "ranges": {1: [[0.5, 1.0]]}}}
    data = load_demonstrations(cfg)
    keep = (t >= 0.5) & (t <= 1.0)
    q, dq = smooth_joints(t[keep] + 1)
    np.testing.assert_allclose(data.X, dh_positions(q), atol=1e-12)
    J = LWR4.chain().jacobian(q, rows=[0, 1, 2])
    np.testing.assert_allclose(data.U, np.einsum("nij,nj->ni", J, dq), atol=1e-12)
    assert data.n_demos == 1 and data.state_names == ["x", "y", "z"]
