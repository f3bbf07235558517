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
