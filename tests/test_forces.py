"""Forces as evidence (issue 30 item 2): a force channel read beside the state by every reader
(base or tool frame), and the contact it shows — phases and rows — in learn-a's ``auto``.

Recordings are simulated (:func:`ccl_cli.simulate.wipe.wipe_log`, the LWR's ``proc_data``) and
written by third-party writers (csv, scipy.io.savemat, h5py, rosbags); the phases and rows
learnt are checked against the simulation's truth.
"""

from __future__ import annotations

import csv
import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io as sio

from ccl_cli.cli import main
from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io import write_demonstrations
from ccl_cli.io.canonical import read_demonstrations
from ccl_cli.io.forces import rotation
from ccl_cli.io.load import load_demonstrations
from ccl_cli.learn.constraint import AutoConstraint, ContactPhases
from ccl_cli.learn.constraint import contact as ct
from ccl_cli.models import load_model, save_model
from ccl_cli.simulate import arm_wipe, arm_wipe_joint
from ccl_cli.simulate.lwr_wipe import lwr_wipe_log, proc_data
from ccl_cli.simulate.recordings import derive
from ccl_cli.simulate.wipe import WIPE, wipe_log


@pytest.fixture(scope="module")
def log():
    return wipe_log(n_demos=3, rate=100.0, seed=0)


@pytest.fixture(scope="module")
def wipe():
    return arm_wipe(n_demos=6, seed=1, force=True)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b)))))


def in_wipe(d: Demonstrations) -> np.ndarray:
    """Where each sample of an arm_wipe dataset is in its labelled wipe phase."""
    keep = np.zeros(d.n_samples, bool)
    for i, p in enumerate(d.metadata["phases"]):
        keep |= (d.demo == i) & (d.t >= p["wipe"][0]) & (d.t < p["wipe"][1])
    return keep


def turning_quaternions(t: np.ndarray, seed: int = 0) -> np.ndarray:
    """Unit quaternions (n, 4) wxyz of a tool that turns smoothly (±40° about a few axes)."""
    rng = np.random.default_rng(seed)
    axis = rng.normal(size=3)
    axis /= np.linalg.norm(axis)
    half = np.radians(40.0) * np.sin(0.7 * t + rng.uniform(0, 6)) / 2 + 0.3
    return np.c_[np.cos(half), np.sin(half)[:, None] * axis]


def tool_frame(force: np.ndarray, q_wxyz: np.ndarray) -> np.ndarray:
    """The base-frame force (n, 3) as a tool-frame sensor reads it: Rᵀ f."""
    return np.einsum("nji,nj->ni", rotation(q_wxyz, "wxyz", ""), force)


# -- the readers ---------------------------------------------------------------------------------
def test_csv_columns_give_the_force_and_its_bias_is_reported(tmp_path, log):
    m = log.demo == 0
    path = tmp_path / "wipe.csv"
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "x", "y", "z", "fx", "fy", "fz"])
        for row in np.c_[log.t[m], log.ee[m], log.wrench[m, :3]]:
            w.writerow([repr(float(v)) for v in row])
    d = load_demonstrations({"state": {"columns": ["x", "y", "z"]}, "force": {"columns": ["fx", "fy", "fz"]}},
                            files=[path])
    assert d.force.shape == (int(m.sum()), 3)
    np.testing.assert_allclose(d.force, log.wrench[m, :3], rtol=0, atol=1e-12)
    bias = next(f for f in d.metadata["files"][0]["faults"] if f["kind"] == "force_bias")
    np.testing.assert_allclose(bias["value"], log.bias[:3], atol=0.1)  # free at both ends: bias ± noise
    assert bias["count"] == 1 and bias["action"] == "reported"


#: The KUKA rim log's mapping (position, wxyz quaternion, force in the flange's frame in X's rows).
MAPPING = {"variable": "proc_data.X", "samples": "columns"}
KUKA = {"format": "mat", "state": {**MAPPING, "columns": [0, 1, 2]}, "time": {"variable": "proc_data.dt"},
        "force": {**MAPPING, "columns": [7, 8, 9], "frame": "tool",
                  "orientation": {**MAPPING, "columns": [3, 4, 5, 6], "convention": "wxyz"}}}


def kuka_file(path: Path, n_demos: int, seed: int) -> tuple[Path, list[dict], object]:
    """The LWR's ``proc_data`` with the force turned into the flange's frame, as the KUKA logs hold
    it, written by scipy.io.savemat: (path, the cells with the base-frame force under "base", the log)."""
    lwr = lwr_wipe_log(n_demos=n_demos, seed=seed)
    cells = proc_data(lwr, seed=seed)
    arr = np.empty((1, len(cells)), dtype=object)
    for i, c in enumerate(cells):
        X = c["X"]
        c["base"] = X[7:10].T.copy()
        X[7:10] = tool_frame(X[7:10].T, X[3:7].T).T
        arr[0, i] = {"X": X, "J": c["J"], "dt": c["dt"]}
    sio.savemat(path, {"proc_data": arr})
    return path, cells, lwr


def test_mat_tool_frame_force_is_rotated_into_the_base_frame(tmp_path):
    path, cells, _ = kuka_file(tmp_path / "rim.mat", 2, 3)
    base = [c["base"] for c in cells]
    mapping, options = MAPPING, KUKA
    d = load_demonstrations(options, files=[path])
    np.testing.assert_allclose(d.force, np.concatenate(base), atol=1e-9)
    # xyzw: the same quaternion's columns in the other order
    xyzw = {**options, "force": {**options["force"], "orientation": {**mapping, "columns": [4, 5, 6, 3],
                                                                      "convention": "xyzw"}}}
    np.testing.assert_allclose(load_demonstrations(xyzw, files=[path]).force, np.concatenate(base), atol=1e-9)
    # read as a base-frame force, the tool-frame numbers are off by the flange's turn (the pressing
    # force, mostly along the table's normal, lies tens of degrees away)
    raw = load_demonstrations({**options, "force": {**mapping, "columns": [7, 8, 9]}}, files=[path])
    pressing = np.linalg.norm(raw.force - raw.force.mean(0), axis=1) > 3.0
    turned = [angle_deg(a, b) for a, b in zip(raw.force[pressing], d.force[pressing], strict=True)]
    assert np.median(turned) > 30


def test_h5py_layout_picks_the_force_columns_of_a_wrench(tmp_path, log):
    path = tmp_path / "layout.h5"
    with h5py.File(path, "w") as f:
        for k in range(3):
            m = log.demo == k
            g = f.create_group(f"demo_{k}")
            g["pos"], g["wrench"], g["t"] = log.ee[m], log.wrench[m], log.t[m]
    options = {"state": {"dataset": "pos"}, "time": {"dataset": "t"}, "demos": {"group": "demo_*"},
               "force": {"dataset": "wrench", "columns": [0, 1, 2]}}
    d = load_demonstrations(options, files=[path])
    np.testing.assert_allclose(d.force, log.wrench[:, :3], atol=0)


def _ros2_bag(path: Path, t_pose: np.ndarray, pos: np.ndarray, quat_xyzw: np.ndarray, t_ft: np.ndarray,
              force: np.ndarray) -> Path:
    from rosbags.rosbag2 import Writer
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS2_HUMBLE)
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    Pose, Point = T["geometry_msgs/msg/Pose"], T["geometry_msgs/msg/Point"]
    Quat = T["geometry_msgs/msg/Quaternion"]
    Wrench, Vec = T["geometry_msgs/msg/Wrench"], T["geometry_msgs/msg/Vector3"]
    origin = 1_700_000_000_000_000_000

    def header(t: float) -> object:
        sec, nsec = divmod(origin + int(round(t * 1e9)), 1_000_000_000)
        return Header(stamp=Time(sec=sec, nanosec=nsec), frame_id="base")

    with Writer(path, version=9) as writer:
        kind = "geometry_msgs/msg/PoseStamped"
        conn = writer.add_connection("/pose", kind, typestore=ts)
        for t, p, q in zip(t_pose, pos, quat_xyzw, strict=True):
            msg = T[kind](header=header(t), pose=Pose(position=Point(x=p[0], y=p[1], z=p[2]),
                                                      orientation=Quat(x=q[0], y=q[1], z=q[2], w=q[3])))
            writer.write(conn, origin + int(t * 1e9), ts.serialize_cdr(msg, kind))
        kind = "geometry_msgs/msg/WrenchStamped"
        conn = writer.add_connection("/ft", kind, typestore=ts)
        for t, f in zip(t_ft, force, strict=True):
            msg = T[kind](header=header(t), wrench=Wrench(force=Vec(x=f[0], y=f[1], z=f[2]),
                                                           torque=Vec(x=0.0, y=0.0, z=0.0)))
            writer.write(conn, origin + int(t * 1e9), ts.serialize_cdr(msg, kind))
    return path


def test_rosbag_wrench_topic_in_the_tool_frame_aligned_onto_the_pose_stamps(tmp_path, log):
    """A WrenchStamped topic at another rate than the PoseStamped state, in the tool's frame: the
    force at the state's stamps (linear interpolation), rotated by the pose's quaternion (ROS order
    xyzw, the default for a topic); the state's samples outside the force's span are dropped."""
    m = log.demo == 0
    t, ee, base = log.t[m], log.ee[m], log.wrench[m, :3]
    q = turning_quaternions(t)
    t_ft = np.arange(t[0] + 0.0123, t[-1], 1 / 333.0)  # 333 Hz, starting after the first pose
    f_ft = np.stack([np.interp(t_ft, t, base[:, j]) for j in range(3)], 1)
    f_tool = tool_frame(f_ft, np.stack([np.interp(t_ft, t, q[:, j]) for j in range(4)], 1) /
                        np.linalg.norm(np.stack([np.interp(t_ft, t, q[:, j]) for j in range(4)], 1), axis=1,
                                       keepdims=True))
    path = _ros2_bag(tmp_path / "bag", t, ee, q[:, [1, 2, 3, 0]], t_ft, f_tool)
    d = load_demonstrations({"state": {"topic": "/pose", "field": "pose.position"},
                             "force": {"topic": "/ft", "field": "wrench.force", "frame": "tool",
                                       "orientation": {"topic": "/pose", "field": "pose.orientation"}}},
                            files=[path])
    inside = (t >= t_ft[0]) & (t <= t_ft[-1])  # two poses before the first force, one after the last
    assert (~inside).sum() == 3 and d.metadata["files"][0]["force_dropped_outside_span"] == 3
    kept = t[inside]
    assert d.n_samples == len(kept)
    truth = np.stack([np.interp(kept, t, base[:, j]) for j in range(3)], 1)
    assert np.abs(d.force - truth).max() < 0.05 * np.abs(base).max()  # two interpolations of a noisy force


def test_canonical_hdf5_keeps_the_force(tmp_path, wipe):
    write_demonstrations(tmp_path / "w.h5", wipe)
    back, _ = read_demonstrations(tmp_path / "w.h5")
    np.testing.assert_array_equal(back.force, wipe.force)
    part = back.subset(back.demo == 2)
    np.testing.assert_array_equal(part.force, wipe.force[wipe.demo == 2])


@pytest.mark.parametrize(("force", "said"), [
    ({"columns": ["fx", "fy"]}, "data.force needs 3 numbers per sample"),
    ({"columns": ["fx", "fy", "fz"], "frame": "tool"}, "frame: tool needs orientation"),
    ({"columns": ["fx", "fy", "fz"], "frame": "tool", "orientation": {"columns": ["x", "y", "z", "fx"]}},
     "convention must say"),
    ({"columns": ["fx", "fy", "fz"], "frame": "tool",
      "orientation": {"columns": ["x", "y", "z", "fx"], "convention": "wxyz"}}, "not a unit quaternion"),
    ({"columns": ["fx", "fy", "fz"], "orientation": {"columns": ["x", "y", "z", "fx"]}},
     "orientation applies to frame: tool"),
])
def test_bad_force_mappings_are_one_line_and_exit_2(tmp_path, capsys, force, said):
    path = tmp_path / "r.csv"
    rows = np.c_[np.arange(40) / 100, np.random.default_rng(0).normal(size=(40, 6))]
    np.savetxt(path, rows, delimiter=",", header="time,x,y,z,fx,fy,fz", comments="")
    config = tmp_path / "c.yaml"
    config.write_text(json.dumps({"data": {"state": {"columns": ["x", "y", "z"]}, "force": force}}))
    code = main(["learn-a", str(path), "-c", str(config), "-o", str(tmp_path / "o"), "-q"])
    message = capsys.readouterr().err.strip()
    assert code == 2 and said in message
    assert len(message.splitlines()) == 1 and "Traceback" not in message and not (tmp_path / "o").exists()


def test_demonstrations_refuse_a_force_of_the_wrong_shape_or_not_finite():
    X, U = np.zeros((5, 3)), np.zeros((5, 3))
    with pytest.raises(InputError, match=r"\(5, 3\), got \(5, 2\)"):
        Demonstrations(X, U, force=np.zeros((5, 2)))
    with pytest.raises(InputError, match="non-finite values \\(first at row 3\\)"):
        Demonstrations(X, U, force=np.r_[np.zeros((3, 3)), np.full((2, 3), np.nan)])


# -- contact -------------------------------------------------------------------------------------
def test_contact_finds_the_wipe_phases_and_the_normal(log):
    U, _ = derive(log.t, log.ee, log.demo, 100.0)
    found = ct.find(log.wrench[:, :3], U, log.demo, log.t)
    truth = log.phase == WIPE
    assert (found.mask == truth).mean() >= 0.99
    assert len(found.stretches) == 3  # one wipe per demonstration
    assert max(angle_deg(s.row, log.normal) for s in found.stretches) < 0.5
    # friction turns each sample's force from the normal by 17° (μ = 0.3); over strokes back and forth
    # the mean force lies near the normal, well inside the cross-check's cone
    assert all(s.angle_deg < 10.0 for s in found.stretches)


def test_contact_is_the_same_in_newtons_and_kilonewtons(log):
    U, _ = derive(log.t, log.ee, log.demo, 100.0)
    a = ct.find(log.wrench[:, :3], U, log.demo, log.t)
    b = ct.find(log.wrench[:, :3] / 1000.0, U, log.demo, log.t)
    np.testing.assert_array_equal(a.mask, b.mask)
    np.testing.assert_allclose(a.rows(), b.rows(), atol=1e-9)


def at_rest(log, seconds: float = 1.0, rate: float = 100.0, seed: int = 0) -> tuple[np.ndarray, ...]:
    """The wipes with the robot waiting ``seconds`` at rest in free air before and after each one (as
    a real log starts and ends): t, positions, force (bias + noise there), phase (free there), demo
    ids, true velocity — each (N, ...)."""
    rng = np.random.default_rng(seed)
    k = int(seconds * rate)
    parts = []
    for d in np.unique(log.demo):
        m = log.demo == d
        t = log.t[m] + seconds
        still = [rng.normal(scale=2e-5, size=(k, 3)) + log.ee[m][i] for i in (0, -1)]
        quiet = [log.bias[:3] + rng.normal(scale=0.2, size=(k, 3)) for _ in range(2)]
        parts.append((np.r_[np.arange(k) / rate, t, t[-1] + np.arange(1, k + 1) / rate],
                      np.r_[still[0], log.ee[m], still[1]], np.r_[quiet[0], log.wrench[m, :3], quiet[1]],
                      np.r_[np.zeros(k, int), log.phase[m], np.full(k, 2)], np.full(m.sum() + 2 * k, d),
                      np.r_[np.zeros((k, 3)), log.ee_vel[m], np.zeros((k, 3))]))
    return tuple(np.concatenate(a) for a in zip(*parts, strict=True))


@pytest.mark.parametrize("push", [0.0, 20.0, 40.0])
def test_a_hand_pushing_along_the_motion_is_not_contact(log, push):
    """Kinesthetic teaching: during approach and retract a hand pushes the tool along its motion —
    up to 40 N, more than the wipe presses (5–15 N): force without a quiet direction near it is no
    contact, and the baseline is read where the robot waits at rest."""
    t, ee, F, phase, demo, vel = at_rest(log)
    U, _ = derive(t, ee, demo, 100.0)
    free = phase != WIPE
    speed = np.linalg.norm(vel, axis=1, keepdims=True)
    F[free] += push * vel[free] / np.maximum(speed[free], 1e-9) * np.clip(speed[free] / 0.05, 0, 1)
    found = ct.find(F, U, demo, t)
    assert (found.mask == (phase == WIPE)).mean() >= 0.99
    assert len(found.stretches) == 3 and max(angle_deg(s.row, log.normal) for s in found.stretches) < 0.5


def test_a_held_channel_gives_no_evidence(log):
    U, _ = derive(log.t, log.ee, log.demo, 100.0)
    F = log.wrench[:, :3].copy()
    m = log.demo == 1
    F[m] = F[np.flatnonzero(m)[0]]  # the sensor stopped updating for this demonstration
    found = ct.find(F, U, log.demo, log.t)
    assert found.held[1] == 1.0 and found.held[0] == 0.0
    assert not found.mask[m].any() and {s.demo for s in found.stretches} == {0, 2}


# -- learn-a's auto --------------------------------------------------------------------------------
def test_auto_decides_by_forces_on_a_whole_wipe(wipe):
    auto = AutoConstraint().fit(wipe.X, wipe.U, groups=wipe.demo, t=wipe.t, derivative=wipe.derivative,
                                force=wipe.force)
    sel = auto.selection_
    assert sel["decided_by"] == "forces" and auto.n_constraints_ == 1
    assert isinstance(auto.chosen_, ContactPhases)
    holds = auto.holds(wipe.X, groups=wipe.demo, t=wipe.t)
    assert (holds == in_wipe(wipe)).mean() >= 0.99
    normal = np.asarray(wipe.metadata["normal"])
    rows = auto.constraint(wipe.X, groups=wipe.demo, t=wipe.t)[holds, 0]
    assert np.degrees(np.arccos(np.abs(rows @ normal).min())) < 0.5
    assert sel["forces"]["heldout"]["supported"] and sel["sure"]["cone"]["median_deg"] < 1.0
    assert sel["forces"]["instead_of"]["decided_by"] in ("states", "velocities")
    assert "the states and velocities alone said" in sel["reason"]


def test_auto_without_forces_keeps_its_answer(wipe):
    plain = AutoConstraint().fit(wipe.X, wipe.U, groups=wipe.demo, t=wipe.t, derivative=wipe.derivative)
    again = AutoConstraint().fit(wipe.X, wipe.U, groups=wipe.demo, t=wipe.t, derivative=wipe.derivative,
                                 force=None)
    assert "forces" not in plain.selection_ and plain.selection_ == again.selection_


def test_forces_support_a_hinge_like_answer_with_more_rows():
    """A slide along x (k = 2: y and z) pushed sideways along y by a hand holding the handle: the
    contact row lies in the answer's rows — the forces support k = 2, they do not cut it to 1."""
    rng = np.random.default_rng(4)
    n_demo, rate = 5, 100.0
    X, F, g, t = [], [], [], []
    for d in range(n_demo):
        s = np.arange(0, 8.0, 1 / rate)
        x = np.where(s < 1, 0.0, np.where(s > 7, 0.45, 0.45 * (1 - np.cos(np.pi * (s - 1) / 6)) / 2))
        pos = np.c_[x, 0.02 * d + 1e-4 * rng.normal(size=len(s)), 0.5 + 1e-4 * rng.normal(size=len(s))]
        moving = (s > 1.2) & (s < 6.8)
        push = np.where(moving, 12.0 + np.sin(2 * s), 0.0)
        F.append(np.c_[0.1 * rng.normal(size=len(s)), push + 0.1 * rng.normal(size=len(s)),
                       0.1 * rng.normal(size=len(s))] + [0.5, -1.0, 2.0])
        X.append(pos)
        g.append(np.full(len(s), d))
        t.append(s)
    X, F, g, t = np.concatenate(X), np.concatenate(F), np.concatenate(g), np.concatenate(t)
    U, how = derive(t, X, g, rate)
    auto = AutoConstraint().fit(X, U, groups=g, t=t, derivative=how, force=F)
    forces = auto.selection_["forces"]
    assert auto.n_constraints_ == 2 and auto.selection_.get("decided_by") != "forces"
    assert forces["role"] == "supporting" and forces["angle_deg"] < 5.0
    assert "forces: supporting" in auto.selection_["reason"]


def test_forces_are_not_used_for_joint_space_actions():
    d = arm_wipe_joint(n_demos=3, rate=100.0, seed=2)
    log = wipe_log(n_demos=3, rate=100.0, velocity_noise=2e-3, seed=2)
    auto = AutoConstraint(candidates=["nhat"]).fit(d.X, d.U, groups=d.demo, t=d.t, force=log.wrench[:, :3])
    assert auto.selection_["forces"] == {"used": False, "reason": "the actions have 7 dimensions; a force "
                                                                   "speaks for 3-D task-space motion"}


def test_contact_phases_save_load_and_a_new_recording(tmp_path, wipe):
    train = wipe.subset(wipe.demo < 4)
    test = wipe.subset(wipe.demo >= 4)
    model = ContactPhases().fit(train.X, train.U, groups=train.demo, t=train.t, force=train.force)
    save_model(tmp_path / "m.h5", model)
    back, _ = load_model(tmp_path / "m.h5")
    np.testing.assert_array_equal(back.projection(train.X, groups=train.demo, t=train.t),
                                  model.projection(train.X, groups=train.demo, t=train.t))
    # a recording it has not seen (no force): its blocks classified by the motion along the rows
    applied = back.applies_to(test.X, test.U, groups=test.demo, t=test.t)
    assert applied.refitted and applied.rule.rule == "stretches classified"
    holds = applied.model.holds(test.X, groups=test.demo, t=test.t)
    assert (holds == in_wipe(test)).mean() >= 0.9


def test_learn_a_reads_the_force_and_reports_the_decision(tmp_path, capsys):
    data = tmp_path / "wipe.h5"
    assert main(["simulate", "arm_wipe_force", "-o", str(data), "--seed", "1", "-q"]) == 0
    out = tmp_path / "out"
    assert main(["learn-a", str(data), "-o", str(out), "-q"]) == 0
    selection = json.loads((out / "metrics.json").read_text())["learn-a"]["selection"]
    assert selection["decided_by"] == "forces" and selection["n_constraints"] == 1
    assert selection["forces"]["role"] == "decided" and selection["forces"]["contact_share"] > 0.6
    report = (out / "report.md").read_text()
    assert "1 constraint in contact, none elsewhere" in report
    assert "Held-out support: the forces' contact stretches" in report
    capsys.readouterr()
    assert main(["inspect", str(out / "model.h5")]) == 0
    assert "method contact" in capsys.readouterr().out


@pytest.mark.parametrize("fmt", ["csv", "mat"])
def test_the_force_stays_with_its_samples_when_faults_drop_some(tmp_path, fmt, log):
    """A spike in the positions is dropped by fault repair: each row's force is still its own
    sample's (the force is a known function of time here)."""
    m = log.demo == 0
    t, ee = log.t[m], log.ee[m].copy()
    ee[200] += [0.3, 0.0, 0.0]  # one sample 30 cm off
    force = np.c_[np.sin(t), np.cos(3 * t), t]
    if fmt == "csv":
        path = tmp_path / "r.csv"
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["time", "x", "y", "z", "fx", "fy", "fz"])
            w.writerows(np.c_[t, ee, force].tolist())
        options = {"state": {"columns": ["x", "y", "z"]}, "force": {"columns": ["fx", "fy", "fz"]}}
    else:
        path = tmp_path / "r.mat"
        sio.savemat(path, {"X": np.c_[ee, force].T, "t": t[:, None]})
        columns = {"variable": "X", "samples": "columns"}
        options = {"format": "mat", "state": {**columns, "columns": [0, 1, 2]}, "time": {"variable": "t"},
                   "force": {**columns, "columns": [3, 4, 5]}}
    d = load_demonstrations(options, files=[path])
    assert d.n_samples == len(t) - 1 and d.repair.counts()["dropped"] == {"spike": 1}
    np.testing.assert_allclose(d.force, np.c_[np.sin(d.t), np.cos(3 * d.t), d.t], atol=1e-9)


def test_a_kuka_style_log_in_the_tool_frame_gives_the_wipe_phases(tmp_path):
    """The LWR's ``proc_data`` (13-row X: position, wxyz quaternion, force, torque) with the force in
    the flange's frame, read with frame: tool: auto finds the labelled wipe phases and the table's
    normal."""
    path, cells, lwr = kuka_file(tmp_path / "lwr.mat", 5, 2)
    labels = []
    for c, phases in zip(cells, lwr.metadata["phases"], strict=True):
        t = np.arange(c["X"].shape[1]) * c["dt"]
        labels.append((t >= phases["wipe"][0]) & (t < phases["wipe"][1]))
    truth = np.concatenate(labels)
    d = load_demonstrations(KUKA, files=[path])
    auto = AutoConstraint().fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative, force=d.force)
    holds = auto.holds(d.X, groups=d.demo, t=d.t)
    assert auto.selection_["decided_by"] == "forces" and (holds == truth).mean() >= 0.98
    rows = auto.constraint(d.X, groups=d.demo, t=d.t)[holds & truth, 0]
    assert np.degrees(np.arccos(np.abs(rows @ lwr.normal).min())) < 1.0
