"""Foreign recordings: HDF5 in any layout, MATLAB .mat (v5 and v7.3), text matrices.

Every file is written at test time by a third-party writer: h5py (a robomimic-like layout,
and MATLAB's v7.3 layout: 512-byte user block with the MATLAB header, transposed arrays,
``MATLAB_class`` attributes, cells as object references into ``#refs#``) and
scipy.io.savemat (v5).
"""

import json
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
import yaml
from writers import write_mat73

from ccl_cli.cli import main
from ccl_cli.errors import InputError
from ccl_cli.io import detect_format, load_demonstrations
from ccl_cli.io import inspect_recording as inspect_path
from ccl_cli.simulate import arm7


# -- writers ------------------------------------------------------------------------------
def write_robomimic(path: Path, demos: list[dict[str, np.ndarray]], names: list[str] | None = None) -> Path:
    """data/demo_K/{obs/joint_pos, obs/joint_vel, t}, one sample per row (as robomimic)."""
    with h5py.File(path, "w") as f:
        data = f.create_group("data")
        data.attrs["total"] = sum(len(d["x"]) for d in demos)
        for k, d in enumerate(demos):
            g = data.create_group(f"demo_{k}")
            pos = g.create_dataset("obs/joint_pos", data=d["x"])
            if names:
                pos.attrs["names"] = names
            g.create_dataset("obs/joint_vel", data=d["u"])
            g.create_dataset("t", data=d["t"])
    return path


def demo_list(data) -> list[dict[str, np.ndarray]]:
    return [{"x": data.X[data.demo == d], "u": data.U[data.demo == d], "t": data.t[data.demo == d]}
            for d in data.demo_ids]


def load(cfg: dict, path: Path):
    return load_demonstrations({**cfg, "files": [str(path)]})


def bad(cfg: dict, path: Path, match: str) -> str:
    with pytest.raises(InputError, match=match) as info:
        load(cfg, path)
    assert "\n" not in info.value.message
    return info.value.message


@pytest.fixture(scope="module")
def arm():
    return arm7(seed=0, n_demos=12, n_steps=20)


ROBOMIMIC = {"format": "hdf5", "demos": {"group": "data/demo_*"}, "state": {"dataset": "obs/joint_pos"},
             "action": {"dataset": "obs/joint_vel"}, "time": {"dataset": "t"}}


# -- HDF5 layouts -------------------------------------------------------------------------
def test_robomimic_layout_round_trip_natural_order(tmp_path, arm):
    path = write_robomimic(tmp_path / "r.hdf5", demo_list(arm), names=[f"j{i}" for i in range(7)])
    data = load(ROBOMIMIC, path)
    # natural sort: demo_10 after demo_9, so the data comes back in the written order
    np.testing.assert_array_equal(data.X, arm.X)
    np.testing.assert_array_equal(data.U, arm.U)
    np.testing.assert_allclose(data.t, arm.t)
    assert data.n_demos == arm.n_demos
    assert data.state_names == [f"j{i}" for i in range(7)]
    assert data.action_names == [f"joint_vel[{i}]" for i in range(7)]
    assert data.metadata["files"][0]["layout"]["demos"] == "data/demo_*"
    picked = load({**ROBOMIMIC, "state": {"dataset": "obs/joint_pos", "columns": ["j1", 3]},
                   "action": {"dataset": "obs/joint_vel", "columns": [1, 3]}}, path)
    np.testing.assert_array_equal(picked.X, arm.X[:, [1, 3]])
    assert picked.state_names == ["j1", "j3"] and picked.action_names == ["joint_vel[1]", "joint_vel[3]"]
    bad({**ROBOMIMIC, "state": {"dataset": "obs/joint_pos", "columns": ["j9"]}}, path,
        r"column 'j9' not found \(names: j0, j1")


def test_flat_layout_with_demo_index_rate_and_derived_action(tmp_path, arm):
    path = tmp_path / "flat.h5"
    with h5py.File(path, "w") as f:
        f["q"] = arm.X
        f["demo_index"] = arm.demo + 100
    data = load({"state": {"dataset": "q"}, "demos": {"dataset": "demo_index"}, "time": {"rate": 20},
                 "action": {"derive": "state"}}, path)
    assert data.n_demos == arm.n_demos
    np.testing.assert_array_equal(data.X, arm.X)
    np.testing.assert_allclose(data.t[data.demo == 0], np.arange(20) / 20)
    # a straight line per demo → the derived action is its exact slope
    with h5py.File(path, "w") as f:
        f["q"] = np.repeat(np.arange(10.0)[:, None], 2, 1) * [1.0, -2.0]
    line = load({"state": {"dataset": "q"}, "time": {"rate": 10}}, path)
    np.testing.assert_allclose(line.U, np.tile([10.0, -20.0], (10, 1)), atol=1e-9)


def test_integer_nanosecond_stamps_stay_exact(tmp_path):
    epoch = 1_700_000_000_123_456_789
    stamps = epoch + np.arange(2000, dtype=np.int64) * 1_000_000 + np.tile([0, 1], 1000)  # 1 kHz, ±1 ns
    path = tmp_path / "ns.h5"
    with h5py.File(path, "w") as f:
        f["q"] = np.arange(2000.0)[:, None]
        f["stamp"] = stamps
    cfg = {"files": [str(path)], "state": {"dataset": "q"}, "time": {"dataset": "stamp"}}
    data = load_demonstrations(cfg)
    # exact to the ns (float64 of the epoch stamps would not be: 256 ns steps)
    np.testing.assert_array_equal(np.round(data.t * 1e9).astype(np.int64), stamps - epoch)
    assert data.metadata["time_origin_ns"] == epoch
    assert data.metadata["files"][0]["layout"]["time"] == "stamp: integer stamps in ns"
    with pytest.raises(InputError, match="not both"):
        load_demonstrations({**cfg, "demos": {"group": "*", "dataset": "x"}})


def test_samples_columns_in_hdf5(tmp_path, arm):
    path = tmp_path / "cols.h5"
    with h5py.File(path, "w") as f:
        f["X"] = arm.X.T
        f["U"] = arm.U.T
    data = load({"state": {"dataset": "X", "samples": "columns"}, "action": {"dataset": "U", "samples":
                 "columns"}, "time": {"rate": 20}}, path)
    np.testing.assert_array_equal(data.U, arm.U)


def test_hdf5_bad_cases_one_line(tmp_path, arm):
    path = write_robomimic(tmp_path / "r.h5", demo_list(arm))
    msg = bad({"format": "hdf5"}, path, "not in the ccl-demonstrations layout")
    assert "data/demo_0/obs/joint_pos (20×7 float64)" in msg and "data.state.dataset" in msg
    bad({**ROBOMIMIC, "state": {"dataset": "obs/nope"}}, path, r"demo_0/obs/nope: missing")
    bad({**ROBOMIMIC, "demos": {"group": "data/run_*"}}, path, "no group matches")
    bad({**ROBOMIMIC, "time": {}}, path, "set data.time.rate")
    bad({**ROBOMIMIC, "state": {"dataset": "obs/joint_pos", "samples": "columns"}}, path,
        "disagree on the number of samples")
    with h5py.File(path, "a") as f:  # ragged: one demo's action is short
        del f["data/demo_3/obs/joint_vel"]
        f["data/demo_3/obs/joint_vel"] = arm.U[:5]
        f["data/demo_4/obs/label"] = np.array([b"a"] * 20)
    bad(ROBOMIMIC, path, "demo_3.*disagree on the number of samples")
    bad({**ROBOMIMIC, "demos": {"group": "data/demo_4"}, "action": {"dataset": "obs/label"}}, path,
        "label: not numeric")


def test_hdf5_external_link_and_storage_refused(tmp_path, arm):
    other = tmp_path / "other.h5"
    with h5py.File(other, "w") as f:
        f["X"] = arm.X
    path = tmp_path / "link.h5"
    with h5py.File(path, "w") as f:
        f["X"] = h5py.ExternalLink(str(other), "X")
    said = bad({"state": {"dataset": "X"}, "time": {"rate": 20}}, path, "external link")
    assert said == f"{path}: /X is an external link to {other}:X; ccl reads nothing outside the file"
    raw = tmp_path / "raw.bin"
    arm.X.astype("<f8").tofile(raw)
    path2 = tmp_path / "ext.h5"
    with h5py.File(path2, "w") as f:
        f.create_dataset("X", shape=arm.X.shape, dtype="<f8", external=[(str(raw), 0, h5py.h5f.UNLIMITED)])
    bad({"state": {"dataset": "X"}, "time": {"rate": 20}}, path2, "stores its data in external file")
    path3 = tmp_path / "virtual.h5"
    with h5py.File(path3, "w") as f:
        layout = h5py.VirtualLayout(shape=arm.X.shape, dtype="f8")
        layout[:] = h5py.VirtualSource(str(other), "X", shape=arm.X.shape)
        f.create_virtual_dataset("X", layout)
    bad({"state": {"dataset": "X"}, "time": {"rate": 20}}, path3, "virtual dataset")


# -- MATLAB .mat --------------------------------------------------------------------------
MAT_CELLS = {"format": "mat", "state": {"variable": "X", "samples": "columns"},
             "action": {"variable": "U", "samples": "columns"}, "time": {"rate": 20}}


def _cells(data, key):
    """One (dims × samples) matrix per demonstration, as a 1-D object array (a cell row for savemat)."""
    out = np.empty(data.n_demos, dtype=object)
    for k, d in enumerate(data.demo_ids):
        out[k] = getattr(data, key)[data.demo == d].T
    return out


def test_mat_v5_cells_one_sample_per_column(tmp_path, arm):
    path = tmp_path / "cells.mat"
    scipy.io.savemat(path, {"X": _cells(arm, "X")[None, :], "U": _cells(arm, "U")[None, :]})
    assert detect_format(path) == "mat"
    data = load(MAT_CELLS, path)
    np.testing.assert_array_equal(data.X, arm.X)
    np.testing.assert_array_equal(data.U, arm.U)
    assert data.n_demos == arm.n_demos
    assert data.state_names[0] == "X[0]"
    # orientation found from the other variable when not given (7×20 matrices share both sides
    # with each other, but the time vector fixes n = 20)
    t = np.empty(arm.n_demos, dtype=object)
    for k, d in enumerate(arm.demo_ids):
        t[k] = arm.t[arm.demo == d][None, :]
    scipy.io.savemat(path, {"X": _cells(arm, "X")[None, :], "U": _cells(arm, "U")[None, :], "t": t[None, :]})
    auto = load({"format": "mat", "state": {"variable": "X"}, "action": {"variable": "U"},
                 "time": {"variable": "t"}}, path)
    np.testing.assert_array_equal(auto.X, arm.X)


def test_mat_v5_struct_fields_matrix_and_demo_index(tmp_path, arm):
    path = tmp_path / "struct.mat"
    scipy.io.savemat(path, {"data": {"X": arm.X.T, "U": arm.U.T, "demo": arm.demo[None, :] + 1.0}})
    data = load({"format": "mat", "state": {"variable": "data.X"}, "action": {"variable": "data.U"},
                 "demos": {"variable": "data.demo"}, "time": {"rate": 20}}, path)
    np.testing.assert_array_equal(data.X, arm.X)
    assert data.n_demos == arm.n_demos
    runs = np.empty((1, 3), dtype=[("X", object), ("U", object)])  # a struct array: one demo per element
    for k in range(3):
        runs[0, k]["X"], runs[0, k]["U"] = arm.X[arm.demo == k].T, arm.U[arm.demo == k].T
    scipy.io.savemat(path, {"run": runs})
    cfg = {**MAT_CELLS, "state": {"variable": "run.X", "samples": "columns"},
           "action": {"variable": "run.U", "samples": "columns"}}
    data = load({**cfg, "time": {"rate": 20}}, path)
    np.testing.assert_array_equal(data.U, arm.select_demos([0, 1, 2]).U)
    assert data.n_demos == 3
    # the same in v7.3 (fields of a struct array are reference datasets)
    elems = [{"X": arm.X[arm.demo == k].T, "U": arm.U[arm.demo == k].T} for k in range(3)]
    v73 = write_mat73(tmp_path / "sa73.mat", {"run": elems})
    np.testing.assert_array_equal(load(cfg, v73).X, arm.select_demos([0, 1, 2]).X)


def test_mat_v5_bad_cases_one_line(tmp_path, arm):
    path = tmp_path / "bad.mat"
    scipy.io.savemat(path, {"X": arm.X.T, "U": arm.U.T, "S": np.eye(7), "name": "text",
                            "C": _cells(arm, "X")[None, :], "data": {"X": arm.X.T}})
    msg = bad({"format": "mat", "time": {"rate": 20}}, path, "data.state.variable is required")
    assert "X (7×240 double)" in msg
    bad({**MAT_CELLS, "state": {"variable": "Y"}}, path, "variable 'Y' not found")
    bad({**MAT_CELLS, "state": {"variable": "data.Z"}}, path, "has no field 'Z'")
    bad({**MAT_CELLS, "state": {"variable": "name"}}, path, "not numeric")
    bad({**MAT_CELLS, "state": {"variable": "X", "samples": "rows"}}, path, "disagree on the number")
    bad({**MAT_CELLS, "state": {"variable": "C"}}, path, "is 240 cells|is a matrix|cell array but")
    bad({"format": "mat", "state": {"variable": "S"}, "time": {"rate": 20}}, path, "square 7×7")
    bad({"format": "mat", "state": {"variable": "X"}, "action": {"variable": "U"}, "time": {"rate": 20}},
        path, "cannot tell which side")


def test_mat_v5_objects_refused(tmp_path):
    # a MATLAB object (class 'inline', as MATLAB writes it) through scipy's own writer types
    from scipy.io.matlab import MatlabObject

    path = tmp_path / "obj.mat"
    rec = np.zeros((1, 1), dtype=[("expr", object)])
    rec[0, 0]["expr"] = np.array(["x+1"])
    scipy.io.savemat(path, {"f": MatlabObject(rec, "inline"), "X": np.ones((2, 5))})
    bad({"format": "mat", "state": {"variable": "f"}, "time": {"rate": 1}}, path, "MATLAB object")


def test_mat73_matrix_demo_index_cells_struct(tmp_path, arm):
    path = write_mat73(tmp_path / "m73.mat", {"X": arm.X.T, "U": arm.U.T, "demo": arm.demo[None, :] + 1.0})
    assert detect_format(path) == "mat"
    cfg = {"format": "mat", "state": {"variable": "X", "samples": "columns"},
           "action": {"variable": "U", "samples": "columns"}, "demos": {"variable": "demo"},
           "time": {"rate": 20}}
    data = load(cfg, path)
    np.testing.assert_array_equal(data.X, arm.X)
    np.testing.assert_array_equal(data.U, arm.U)
    assert data.n_demos == arm.n_demos and data.metadata["files"][0]["mat_version"] == "7.3"
    cells = write_mat73(tmp_path / "c73.mat", {"s": {"X": [arm.X[arm.demo == d].T for d in arm.demo_ids],
                                                     "U": [arm.U[arm.demo == d].T for d in arm.demo_ids]}})
    data = load({**MAT_CELLS, "state": {"variable": "s.X", "samples": "columns"},
                 "action": {"variable": "s.U", "samples": "columns"}}, cells)
    np.testing.assert_array_equal(data.U, arm.U)
    assert data.n_demos == arm.n_demos


def test_mat73_bad_cases_one_line(tmp_path, arm):
    path = write_mat73(tmp_path / "b73.mat", {"X": arm.X.T, "U": arm.U[:100].T, "name": "abc"})
    with h5py.File(path, "a") as f:
        f["fh"] = np.zeros((1, 1))
        f["fh"].attrs["MATLAB_class"] = np.bytes_("function_handle")
        f["link"] = h5py.ExternalLink("elsewhere.mat", "X")
    bad({**MAT_CELLS, "demos": {}}, path, "external link")
    with h5py.File(path, "a") as f:
        del f["link"]
    bad({**MAT_CELLS, "state": {"variable": "fh"}}, path, "never loads MATLAB objects")
    bad({**MAT_CELLS, "state": {"variable": "name"}}, path, "not numeric")
    bad(MAT_CELLS, path, "disagree on the number of samples")
    bad({**MAT_CELLS, "state": {"variable": "nope"}}, path, r"variable 'nope' not found \(variables: U, X")


def test_inspect_lists_trees(tmp_path, arm):
    path = write_mat73(tmp_path / "t.mat", {"X": arm.X.T, "s": {"U": [arm.U[:5].T]}})
    info = inspect_path(path)
    tree = {e["path"]: e for e in info["tree"]}
    assert info["format"] == "mat"
    assert tree["X"]["shape"] == [7, 240] and tree["X"]["class"] == "double"
    assert tree["s"]["class"] == "struct" and tree["s/U"]["class"] == "cell"
    assert not any(p.startswith("#") for p in tree)
    v5 = tmp_path / "t5.mat"
    scipy.io.savemat(v5, {"X": arm.X.T, "data": {"U": arm.U.T}})
    tree5 = {e["path"]: e for e in inspect_path(v5)["tree"]}
    assert tree5["X"]["shape"] == [7, 240] and tree5["data.U"]["shape"] == [7, 240]
    h5 = write_robomimic(tmp_path / "r.h5", demo_list(arm))
    info = inspect_path(h5, ROBOMIMIC)
    assert info["demos"] == arm.n_demos and info["samples_per_demo"] == [20] * arm.n_demos
    assert {"path": "data/demo_0/t", "kind": "dataset", "shape": [20], "dtype": "float64"} in info["tree"]


# -- the bars: 7-DoF rank-2 arm through each format, learn-a nhat → predict on held-out demos ----
def _bar(tmp_path, capsys, writer, cfg):
    full = arm7(seed=0, n_demos=40)
    train, held = full.select_demos(list(range(30))), full.select_demos(list(range(30, 40)))
    train_file, held_file = writer(tmp_path / "train", train), writer(tmp_path / "held", held)
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"data": cfg, "output": {"plots": False}}))
    assert main(["learn-a", str(train_file), "-c", str(config), "--method", "nhat", "--test-fraction", "0",
                 "-o", str(tmp_path / "out"), "-q"]) == 0, capsys.readouterr().err
    assert main(["predict", str(tmp_path / "out" / "model.h5"), str(held_file), "-c", str(config),
                 "-o", str(tmp_path / "pred.h5"), "-q"]) == 0, capsys.readouterr().err
    with h5py.File(tmp_path / "pred.h5") as f:
        N, X = f["N"][()], f["x"][()]
    np.testing.assert_array_equal(X, held.X)  # the held-out demonstrations, in order
    err = float(np.abs(N - held.true_projection()).max())
    assert err < 1e-3, err
    return err


def test_bar_arm7_robomimic_hdf5(tmp_path, capsys):
    _bar(tmp_path, capsys, lambda p, d: write_robomimic(p.with_suffix(".hdf5"), demo_list(d)), ROBOMIMIC)


def test_bar_arm7_mat_v5_cells(tmp_path, capsys):
    def writer(p, d):
        scipy.io.savemat(p.with_suffix(".mat"), {"X": _cells(d, "X")[None, :], "U": _cells(d, "U")[None, :]})
        return p.with_suffix(".mat")

    _bar(tmp_path, capsys, writer, MAT_CELLS)


def test_bar_arm7_mat73_matrix_demo_index(tmp_path, capsys):
    cfg = {**MAT_CELLS, "demos": {"variable": "demo"}}
    _bar(tmp_path, capsys, lambda p, d: write_mat73(p.with_suffix(".mat"), {
        "X": d.X.T, "U": d.U.T, "demo": d.demo[None, :].astype(float)}), cfg)
    # convert and evaluate read the same file with the same -c config
    held, config = tmp_path / "held.mat", tmp_path / "c.yaml"
    assert main(["convert", str(held), "-c", str(config), "-o", str(tmp_path / "held.h5"), "-q"]) == 0
    with h5py.File(tmp_path / "held.h5") as f:
        assert np.diff(f["demos/offsets"][()]).tolist() == [40] * 10 and f["demos/x"].shape == (400, 7)
    assert main(["evaluate", str(tmp_path / "out" / "model.h5"), str(held), "-c", str(config), "--json",
                 "-q"]) == 0
    metrics = json.loads(capsys.readouterr().out)["metrics"]
    assert metrics["NPOE"] < 1e-3, metrics  # no ground truth in a .mat: the observed-action error


def test_cli_inspect_lists_the_tree_and_demos(tmp_path, capsys, arm):
    path = write_robomimic(tmp_path / "r.hdf5", demo_list(arm))
    config = tmp_path / "c.yaml"
    config.write_text(yaml.safe_dump({"data": ROBOMIMIC}))
    assert main(["inspect", str(path), "-c", str(config)]) == 0
    out = capsys.readouterr().out
    assert "data/demo_11/obs/joint_pos  dataset  [20, 7]  float64" in out
    assert "demos:    12" in out and "samples_per_demo: [20," in out


def test_cli_bad_mat_exit_2(tmp_path, capsys):
    path = tmp_path / "x.mat"
    scipy.io.savemat(path, {"X": np.ones((3, 10))})
    code = main(["convert", str(path), "-o", str(tmp_path / "o.h5")])
    err = capsys.readouterr().err
    assert code == 2 and err.count("\n") == 1 and "data.state.variable is required" in err
    assert not (tmp_path / "o.h5").exists()
    json.dumps(inspect_path(path))  # the tree is JSON-able


# -- text matrices (the original C library's data files) ------------------------------------
TEXT = {"format": "csv", "state": {"samples": "columns"}, "action": {"file": "U.txt", "samples": "columns"},
        "time": {"rate": 20}}


def test_text_matrices_one_sample_per_column_one_file_per_variable(tmp_path, arm):
    for d in arm.demo_ids[:3]:  # one folder per demonstration: X.txt (p×n), U.txt (q×n)
        folder = tmp_path / f"demo{d}"
        folder.mkdir()
        np.savetxt(folder / "X.txt", arm.X[arm.demo == d].T)
        np.savetxt(folder / "U.txt", arm.U[arm.demo == d].T, delimiter="\t")
    data = load_demonstrations({**TEXT, "files": [str(tmp_path / "demo*" / "X.txt")]})
    first3 = arm.select_demos(arm.demo_ids[:3])
    np.testing.assert_array_equal(data.X, first3.X)  # %.18e text round-trips float64 exactly
    np.testing.assert_array_equal(data.U, first3.U)
    assert data.n_demos == 3 and data.state_names[0] == "X[0]" and data.action_names[6] == "U[6]"
    info = inspect_path(tmp_path / "demo0" / "X.txt", {**TEXT, "files": []})
    assert info["sample_axis"] == "columns" and info["rows"] == 20 and len(info["columns"]) == 7


def test_text_matrix_bad_cases_one_line(tmp_path, arm):
    np.savetxt(tmp_path / "X.txt", arm.X[:20].T)
    np.savetxt(tmp_path / "U.txt", arm.U[:20])  # one sample per row: the wrong orientation
    cfg = {**TEXT, "files": [str(tmp_path / "X.txt")]}
    bad_ = pytest.raises(InputError, match="20 state samples but 7 action samples in U.txt")
    with bad_:
        load_demonstrations(cfg)
    (tmp_path / "U.txt").write_text("1 2 3\n4 5\n")
    with pytest.raises(InputError, match="row 2 has 2 fields, row 1 has 3"):
        load_demonstrations(cfg)
    (tmp_path / "U.txt").write_text("1 2 x\n4 5 6\n")
    with pytest.raises(InputError, match="samples: columns needs a text matrix without a header"):
        load_demonstrations(cfg)
    with pytest.raises(InputError, match="no such file"):
        load_demonstrations({**cfg, "action": {"file": "V.txt"}})
    with pytest.raises(InputError, match="no time column"):
        load_demonstrations({**cfg, "time": {}})
