"""Readers on what users bring: a scalar sampling interval in a .mat beside cell arrays, a
rosbag→CSV export with text columns, and a tracker whose poses repeat between updates."""

import json

import numpy as np
import pytest
import scipy.io

from ccl_cli.cli import main
from ccl_cli.io import read_dataset


def _cells(*arrays) -> np.ndarray:
    out = np.empty((1, len(arrays)), dtype=object)
    for k, a in enumerate(arrays):
        out[0, k] = a
    return out


def _arc(n: int, dt: float, k: int) -> tuple[np.ndarray, np.ndarray]:
    """An arc on the plane z = 0.3 sampled every dt: states (3, n), velocities (3, n), one per
    column as the original library stores them."""
    t = np.arange(n) * dt
    X = np.vstack([np.cos(t + k), np.sin(t + k), 0.3 + 0 * t])
    U = np.vstack([-np.sin(t + k), np.cos(t + k), 0 * t])
    return X, U


@pytest.mark.parametrize("version", ["5", "7.3"])
def test_a_scalar_dt_beside_cell_arrays_is_the_sampling_interval_of_every_cell(tmp_path, capsys, version):
    from writers import write_mat73

    (X1, U1), (X2, U2) = _arc(300, 0.01, 0), _arc(250, 0.01, 1)
    path = tmp_path / "demos.mat"
    if version == "5":
        scipy.io.savemat(path, {"X": _cells(X1, X2), "U": _cells(U1, U2), "dt": 0.01})
    else:
        write_mat73(path, {"X": [X1, X2], "U": [U1, U2], "dt": 0.01})
    options = {"format": "mat", "state": {"variable": "X", "samples": "columns"},
               "action": {"variable": "U", "samples": "columns"}, "time": {"variable": "dt"}}
    data, _ = read_dataset(options, [path])
    assert data.n_demos == 2 and data.n_samples == 550
    for d, n in zip(data.demo_ids, (300, 250), strict=True):
        t = data.t[data.demo == d]
        np.testing.assert_allclose(t - t[0], np.arange(n) * 0.01, rtol=0, atol=1e-12)
    np.testing.assert_array_equal(data.X[:300], X1.T)
    if version == "5":  # inspect shows the number, and what takes it
        assert main(["inspect", str(path)]) == 0
        assert "dt  variable  [1, 1]  double  = 0.01 (one number: time: {variable: dt} takes it as the " \
               "sampling interval)" in capsys.readouterr().out


def _rostopic_csv(path, frame_first: bool = False, n: int = 200) -> np.ndarray:
    """A `rostopic echo -p`-style export of PoseStamped, written with the csv module: %time and
    the header's seq, stamp (int ns) and frame_id (text), then the pose; returns the positions."""
    import csv

    t = 1_500_000_000_000_000_000 + np.arange(n) * 10_000_000
    s = np.arange(n) * 0.01
    P = np.c_[0.2 * np.cos(s), 0.2 * np.sin(s), 0.4 + 0 * s]
    header = ["%time", "field.header.seq", "field.header.stamp", "field.header.frame_id"]
    if frame_first:
        header = ["%time", "field.header.frame_id", "field.header.seq", "field.header.stamp"]
    header += [f"field.pose.position.{a}" for a in "xyz"] + [f"field.pose.orientation.{a}" for a in "xyzw"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for i in range(n):
            head = {"%time": t[i] + 1234, "field.header.seq": i, "field.header.stamp": t[i],
                    "field.header.frame_id": "world"}
            w.writerow([head[h] for h in header[:4]] + [repr(float(v)) for v in P[i]] + [0, 0, 0, 1])
    return P


@pytest.mark.parametrize("frame_first", [False, True])
def test_a_rostopic_csv_export_lists_its_text_columns_and_reads(tmp_path, capsys, frame_first):
    path = tmp_path / "pose.csv"
    P = _rostopic_csv(path, frame_first)
    assert main(["inspect", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["text_columns"] == ["field.header.frame_id"]
    assert info["time_column"] == "%time" and info["rows"] == 200
    assert abs(info["rate_hz"] - 100.0) < 1e-6 and info["demos"] == 1
    assert main(["inspect", str(path)]) == 0
    assert "text:     field.header.frame_id (text, not numbers: never a state or an action)" in \
        capsys.readouterr().out
    cols = [f"field.pose.position.{a}" for a in "xyz"]
    data, _ = read_dataset({"state": {"columns": cols}, "action": {"derive": "state"}}, [path])
    np.testing.assert_array_equal(data.X, P)
    assert data.state_names == cols
    # a text column asked for as a state is one line naming it
    assert main(["learn-a", str(path), "-c", _cfg(tmp_path, ["field.header.frame_id"])]) == 2
    assert "'field.header.frame_id' row 2 is not numeric ('world')" in capsys.readouterr().err


def _cfg(tmp_path, columns) -> str:
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{state: {{columns: {columns}}}, action: {{derive: state}}}}\n")
    return str(cfg)


# -- repeated poses: a tracker logged faster than it updates -----------------------------------
def _pose(t: np.ndarray) -> np.ndarray:
    return np.c_[0.1 * np.sin(0.7 * t) + 0.05 * np.sin(1.9 * t),
                 0.1 * np.cos(0.5 * t) + 0.03 * np.sin(2.3 * t), 0.2 + 0.01 * np.sin(0.7 * t)]


def _velocity(t: np.ndarray) -> np.ndarray:
    return np.c_[0.07 * np.cos(0.7 * t) + 0.095 * np.cos(1.9 * t),
                 -0.05 * np.sin(0.5 * t) + 0.069 * np.cos(2.3 * t), 0.007 * np.cos(0.7 * t)]


def _held_tracker(path, seconds: float = 30.0, rest: tuple[float, float] | None = None, seed: int = 0
                  ) -> tuple[np.ndarray, np.ndarray]:
    """Rows logged at 417 Hz (stamps jittering ±50 %) of a pose that updates at 29 Hz, each row the
    latest pose (numpy.savetxt, header time,x,y,z); ``rest``: the sensor holds still from .. to
    (s), reporting the same pose at every update. Returns the stamps and each pose's update time."""
    rng = np.random.default_rng(seed)
    log_t = np.cumsum(rng.uniform(0.5, 1.5, int(seconds * 417)) / 417)
    updates = np.arange(0, seconds + 1, 1 / 29.0)
    moving = updates
    if rest is not None:  # the pose's own clock stops while it rests
        moving = np.where(updates < rest[0], updates,
                          np.where(updates < rest[1], rest[0], updates - (rest[1] - rest[0])))
    which = np.searchsorted(updates, log_t, side="right") - 1
    np.savetxt(path, np.c_[log_t, _pose(moving)[which]], delimiter=",", header="time,x,y,z", comments="",
               fmt="%.9f")
    return log_t, moving[which]


def _read(path, **faults):
    options = {"state": {"columns": ["x", "y", "z"]}, "action": {"derive": "state"}}
    return read_dataset(options | ({"faults": faults} if faults else {}), [path])[0]


def test_repeated_poses_are_left_out_and_velocities_come_from_the_updates(tmp_path):
    from ccl_cli import diagnostics

    path = tmp_path / "tracker.csv"
    log_t, shown = _held_tracker(path)
    poses = len(np.unique(shown))
    data = _read(path)
    assert data.n_samples == poses  # one sample per update, at its first stamp
    truth = _velocity(shown[np.r_[True, np.diff(shown) > 0]])
    err = np.sqrt(np.sum((data.U - truth) ** 2, 1).mean() / np.sum(truth**2, 1).mean())
    assert err < 0.015 and not (np.linalg.norm(data.U, axis=1) < 1e-9).any()
    warnings = diagnostics.check_data(data)
    codes = [w["code"] for w in warnings]
    assert "repeated_poses" in codes and "jittery_stamps" not in codes
    said = next(w["message"] for w in warnings if w["code"] == "repeated_poses")
    assert "the sensor updates at 29 Hz, its samples were logged at 417 Hz: each pose is repeated 14 " \
        "times" in said
    assert f"the {len(log_t) - poses} repeats were left out" in said
    # kept as recorded: every row, and the velocities of a staircase (zero between jumps, with a short window)
    kept = _read(path, stamps="keep")
    assert kept.n_samples == len(log_t)
    truth_all = _velocity(shown)
    err_all = np.sqrt(np.sum((kept.U - truth_all) ** 2, 1).mean() / np.sum(truth_all**2, 1).mean())
    assert err_all > 2 * err
    short = read_dataset({"state": {"columns": ["x", "y", "z"]}, "action": {"derive": "state", "window": 5},
                          "faults": {"stamps": "keep"}}, [path])[0]
    assert (np.linalg.norm(short.U, axis=1) < 1e-9).mean() > 0.5
    assert any(w["code"] == "repeated_poses" and "kept as recorded" in w["message"]
               for w in diagnostics.check_data(kept))


def test_a_pose_held_at_rest_keeps_one_sample_per_update(tmp_path):
    path = tmp_path / "rest.csv"
    log_t, shown = _held_tracker(path, rest=(10.0, 12.0))
    data = _read(path)
    t = data.t + log_t[0]
    still = (t > 10.05) & (t < 11.95)
    assert abs(int(still.sum()) - 55) <= 2  # 1.9 s of updates at 29 Hz
    assert np.abs(data.U[still][5:-5]).max() < 1e-9  # at rest: no motion, and no gap in the stamps
    assert np.diff(t[still]).max() < 1.5 / 29


@pytest.mark.parametrize("kind", ["quantised", "every_sample"])
def test_values_that_repeat_without_a_steady_update_are_no_repeated_poses(kind):
    from ccl_cli.io.faults import repeated_poses

    rng = np.random.default_rng(3)
    t = np.arange(5000) * 0.002
    if kind == "quantised":  # an encoder crawling: its count changes when the motion crosses one
        X = np.round(np.cumsum(rng.normal(0, 2e-4, (5000, 3)), 0), 3)
    else:  # still for half the recording, then new at every sample
        X = np.r_[np.zeros((3000, 3)), np.cumsum(rng.normal(0, 1e-3, (2000, 3)), 0)]
    assert (np.diff(X, axis=0) == 0).all(1).mean() > 0.5
    assert not repeated_poses(t, X, np.zeros(5000, int))


def test_predict_and_inspect_say_what_became_of_the_repeats(tmp_path, capsys):
    import csv

    path = tmp_path / "tracker.csv"
    log_t, shown = _held_tracker(path, seconds=20)
    poses = len(np.unique(shown))
    assert main(["inspect", str(path), "--json"]) == 0
    repeats = json.loads(capsys.readouterr().out)["repeats"]
    assert repeats["rows"] == len(log_t) - poses and abs(repeats["rate_hz"] - 29) < 0.1
    assert repeats["per_pose"] in (14.0, 15.0) and repeats["columns"] == ["x", "y", "z"]
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {state: {columns: [x, y, z]}, action: {derive: state}}\n"
                   "output: {plots: false}\n")
    assert main(["learn-a", str(path), "-c", str(cfg), "-o", str(tmp_path / "m"), "-q"]) == 0
    assert main(["predict", str(tmp_path / "m" / "model.h5"), str(path), "-c", str(cfg), "-o",
                 str(tmp_path / "p.csv"), "-q"]) == 0
    with open(tmp_path / "p.csv", newline="") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == len(log_t)  # one row per sample read
    filled = [r for r in rows if r["repair"] == "filled"]
    assert len(filled) == len(log_t) - poses and {r["fault"] for r in filled} == {"repeated_pose"}
