"""Phases and MATLAB files as researchers save them (issue 18, items 2 and 3).

Every .mat file is written at test time by scipy.io.savemat (v5) or h5py in MATLAB's v7.3
layout (tests/writers.py); CSV by the csv module; canonical HDF5 by ccl's own writer from a
simulated recording. The bars: a simulated KUKA LWR 4+ wiping log in the researchers' layout
(proc_data, a 1×D cell of structs with X 13×T, J 7×T, dt) learnt with nhat per demonstration,
each wipe's normal within 8° of the plane fitted to its positions (task space X, and forward
kinematics of J with a URDF written from the LWR's DH table).
"""

import csv
import json

import numpy as np
import pytest
import scipy.io
import yaml
from writers import Cell, write_mat73

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.errors import InputError
from ccl_cli.io import inspect_recording, load_demonstrations, read_dataset, write_demonstrations
from ccl_cli.io.segment import cut, segment_ids
from ccl_cli.learn.robots import LWR4
from ccl_cli.models import load_model
from ccl_cli.simulate.lwr_wipe import lwr_wipe_log, proc_data, wipe_ranges


def save_cells_v5(path, cells: list[dict]) -> None:
    """``proc_data``: a 1×D cell array of structs, as MATLAB saves it (scipy writes dicts as structs)."""
    arr = np.empty((1, len(cells)), dtype=object)
    for k, c in enumerate(cells):
        arr[0, k] = c
    scipy.io.savemat(path, {"proc_data": arr})


def demo_cells(rng, n_demos=3):
    """D structs {X 4×T (one sample per column), F 3×T force, dt}: X rows 0..2 a known ramp."""
    cells = []
    for d in range(n_demos):
        T = 40 + 10 * d
        dt = 0.01 * (1 + 0.1 * d)
        X = np.vstack([np.arange(T) * (d + 1.0), np.sin(np.arange(T)), rng.normal(size=(2, T))])
        F = np.zeros((3, T))
        F[2, 10:25] = 8.0  # contact from sample 10 to 24
        F[0, 30:33] = 6.0  # a touch of 3 samples (too short for min_duration)
        cells.append({"X": X, "F": F, "dt": dt})
    return cells


CELL_CFG = {"format": "mat", "state": {"variable": "proc_data.X", "samples": "columns", "columns": [0, 1]},
            "time": {"variable": "proc_data.dt"}}


def load(cfg, path):
    return load_demonstrations({**cfg, "files": [str(path)]})


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_fields_of_structs_in_cells_with_a_sampling_interval_per_demonstration(tmp_path, version):
    cells = demo_cells(np.random.default_rng(0))
    path = tmp_path / "log.mat"
    if version == "v5":
        save_cells_v5(path, cells)
    else:
        write_mat73(path, {"proc_data": Cell(cells)})
    data = load(CELL_CFG, path)
    assert data.n_demos == 3 and data.state_names == ["proc_data.X[0]", "proc_data.X[1]"]
    for d, c in enumerate(cells):
        rows = data.demo == d
        np.testing.assert_array_equal(data.X[rows], c["X"][:2].T)
        np.testing.assert_allclose(data.t[rows], np.arange(c["X"].shape[1]) * c["dt"], rtol=1e-12)
        # the ramp's derivative is (d + 1) per sample / dt
        np.testing.assert_allclose(data.U[rows, 0], (d + 1) / c["dt"], rtol=1e-9)
    # inspect lists each cell's struct fields with their shapes (MATLAB's orientation)
    tree = {e["path"]: e for e in inspect_recording(path, {"format": "mat"})["tree"]}
    assert tree["proc_data{2}.X"]["shape"] == [4, 50] and tree["proc_data{3}.dt"]["shape"] == [1, 1]
    assert tree["proc_data{1}"]["class"] == "struct"


def test_a_bad_sampling_interval_is_one_line(tmp_path):
    cells = demo_cells(np.random.default_rng(0))
    cells[1]["dt"] = -0.01
    save_cells_v5(tmp_path / "log.mat", cells)
    with pytest.raises(InputError, match=r"proc_data.dt\{2\}: a sampling interval must be a positive"):
        load(CELL_CFG, tmp_path / "log.mat")


def test_per_demonstration_ranges_in_a_mat_file(tmp_path):
    cells = demo_cells(np.random.default_rng(1))
    save_cells_v5(tmp_path / "log.mat", cells)
    # demo 0: 0.10–0.20 s; demo 1: dropped (not named); demo 2: two phases
    ranges = {0: [[0.1, 0.2]], 2: [[0.0, 0.12], [0.24, 0.36]]}
    data = load({**CELL_CFG, "demos": {"ranges": ranges}}, tmp_path / "log.mat")
    assert data.n_demos == 3
    dt0, dt2 = cells[0]["dt"], cells[2]["dt"]
    expected = [np.arange(10, 21) * dt0, np.arange(0, 11) * dt2, np.arange(20, 31) * dt2]
    for d, t in enumerate(expected):
        np.testing.assert_allclose(data.t[data.demo == d], t, atol=1e-12)
    np.testing.assert_array_equal(data.X[data.demo == 2][:, 0], np.arange(20, 31) * 3.0)
    assert data.metadata["files"][0]["demos"][0] == "proc_data.X{1} [0.1, 0.2] s"


def test_where_a_force_is_above_a_level_each_stretch_is_a_demonstration(tmp_path):
    cells = demo_cells(np.random.default_rng(2))
    save_cells_v5(tmp_path / "log.mat", cells)
    where = {"variable": "proc_data.F", "samples": "columns", "norm_above": 5.0}
    data = load({**CELL_CFG, "demos": {"where": where}}, tmp_path / "log.mat")
    assert data.n_demos == 6  # per demonstration: the contact and the short touch
    assert np.bincount(data.demo).tolist() == [15, 3] * 3
    short = load({**CELL_CFG, "demos": {"where": where, "min_duration": 0.05}}, tmp_path / "log.mat")
    assert np.bincount(short.demo).tolist() == [15] * 3
    np.testing.assert_allclose(short.t[short.demo == 1], np.arange(10, 25) * cells[1]["dt"], atol=1e-12)
    # a column of the signal, by index; and a level below
    only_z = load({**CELL_CFG, "demos": {"where": {**where, "columns": [2]}}}, tmp_path / "log.mat")
    assert np.bincount(only_z.demo).tolist() == [15] * 3
    free = load({**CELL_CFG, "demos": {"where": {"variable": "proc_data.F", "samples": "columns",
                                                  "norm_below": 1.0}, "min_duration": 0.05}},
                tmp_path / "log.mat")
    # before the contact and after the touch; the 0.04 s between contact and touch is too short
    assert free.n_demos == 6 and np.bincount(free.demo)[:2].tolist() == [10, 7]
    with pytest.raises(InputError, match="demos.where needs a level: norm_above and/or norm_below"):
        load({**CELL_CFG, "demos": {"where": {"variable": "proc_data.F"}}}, tmp_path / "log.mat")
    with pytest.raises(InputError, match="demos.where needs variable"):
        load({**CELL_CFG, "demos": {"where": {"column": "F", "norm_above": 1}}}, tmp_path / "log.mat")


def write_force_csv(path, t, pos, force):
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["time", "x", "y", "fx", "fy", "fz"])
        w.writerows([[repr(float(a)), *map(repr, p.tolist()), *map(repr, g.tolist())]
                     for a, p, g in zip(t, pos, force, strict=True)])
    return path


def test_where_cut_and_per_demo_ranges_in_a_csv_stream(tmp_path):
    t = np.arange(600) / 100.0
    pos = np.c_[np.sin(t), np.cos(t)]
    force = np.zeros((600, 3))
    force[100:250, 2] = 10.0  # contact 1.00–2.49 s
    force[400:560, 1] = -7.0  # contact 4.00–5.59 s
    force[300:310, 0] = 6.0  # a 0.1-s bump
    path = write_force_csv(tmp_path / "log.csv", t, pos, force)
    cfg = {"files": [str(path)], "time": {"column": "time"}, "state": {"columns": ["x", "y"]},
           "demos": {"where": {"columns": ["fx", "fy", "fz"], "norm_above": 5.0}, "min_duration": 0.5}}
    data = load_demonstrations(cfg)
    assert np.bincount(data.demo).tolist() == [150, 160]
    t_read = data.t + 1.0  # stamps count from the first sample kept (1.00 s)
    np.testing.assert_allclose(t_read[data.demo == 1][[0, -1]], [4.0, 5.59], atol=1e-9)
    np.testing.assert_allclose(data.U, np.c_[np.cos(t_read), -np.sin(t_read)], atol=5e-3)
    # the same recording cut on pauses, then a phase per demonstration by ranges
    t2 = np.r_[t[:300], t[300:] + 2.0]  # a 2-s pause after 3 s
    path = write_force_csv(tmp_path / "gap.csv", t2, pos, force)
    ranges = load_demonstrations({"files": [str(path)], "time": {"column": "time"},
                                  "state": {"columns": ["x", "y"]},
                                  "demos": {"split_on_gap": 1.0,
                                            "ranges": {0: [[1.0, 2.0]], 1: [[0.5, 1.0]]}}})
    assert np.bincount(ranges.demo).tolist() == [101, 51]
    np.testing.assert_allclose(ranges.X[ranges.demo == 1][0], pos[350], atol=1e-12)


def test_cut_steps_by_hand():
    t = np.r_[np.arange(0, 3, 0.5), np.arange(10, 12, 0.5)]  # two demonstrations by the gap
    ids, n_base = cut(t, {"split_on_gap": 2, "ranges": {1: [[0.5, 1.0]]}}, "f")
    assert n_base == 2 and ids.tolist() == [-1] * 6 + [-1, 0, 0, -1]
    ids, _ = cut(t, {"split_on_gap": 2, "ranges": {0: [[0, 1.0]]}}, "f", first=1)  # keys count on
    assert (ids < 0).all()
    passes = np.array([1, 1, 0, 1, 1, 1, 1, 1, 0, 1], bool)
    ids = segment_ids(t, {"split_on_gap": 2, "where": {"column": 0, "norm_above": 0},
                          "min_duration": 0.5}, "f", passes)
    assert ids.tolist() == [0, 0, -1, 1, 1, 1, 2, 2, -1, -1]
    with pytest.raises(InputError, match="no samples left after the demos cuts"):
        segment_ids(t, {"ranges": {5: [[0, 1]]}}, "f")
    with pytest.raises(InputError, match="needs its signal"):
        segment_ids(t, {"where": {"column": 0, "norm_above": 0}}, "f")


def test_canonical_hdf5_per_demo_ranges_keep_masks(tmp_path):
    data = sim.toy2d(constraint="fixed", n_demos=4, seed=0)
    path = tmp_path / "toy.h5"
    write_demonstrations(path, data)
    ranges = {1: [[0.0, 0.5]], 3: [[0.2, 0.4]]}
    cut_data, _ = read_dataset({"files": [str(path)], "demos": {"ranges": ranges}})
    assert cut_data.n_demos == 2
    for new, old in ((0, 1), (1, 3)):
        t_old = data.t[data.demo == old] - data.t[data.demo == old][0]
        lo, hi = ((0.0, 0.5), (0.2, 0.4))[new]
        keep = (t_old >= lo) & (t_old <= hi)
        np.testing.assert_array_equal(cut_data.X[cut_data.demo == new], data.X[data.demo == old][keep])


# -- the bars: a KUKA LWR 4+ wiping log, in the researchers' MATLAB layout ---------------------
@pytest.fixture(scope="module")
def lwr_log():
    return lwr_wipe_log(n_demos=3, seed=3, wipe_s=(3.0, 4.0), force=(8.0, 15.0), bias=0.3)


def _angle(a, b):
    return float(np.degrees(np.arccos(min(1.0, abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b)))))


def _learn_and_compare(tmp_path, capsys, data_cfg, name):
    cfg = tmp_path / f"{name}.yaml"
    cfg.write_text(yaml.safe_dump({"data": data_cfg, "learn-a": {"method": "nhat", "per_demo": True},
                                   "stages": ["learn-a"]}))
    assert main(["inspect", "-c", str(cfg), data_cfg["files"][0], "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["demos"] == 3
    out = tmp_path / f"out_{name}"
    assert main(["learn-a", "-c", str(cfg), "-o", str(out), "--quiet"]) == 0
    capsys.readouterr()
    model, _ = load_model(out / "model.h5")
    data = load_demonstrations(data_cfg, base=tmp_path)
    angles = []
    assert len(model.models_) == 2  # 3 demonstrations: one held out whole (test split), one model each
    for d in model.models_:
        X = data.X[data.demo == d]
        plane = np.linalg.svd(X - X.mean(0))[2][-1]  # the normal of the plane fitted to the positions
        _, vecs = np.linalg.eigh(model.models_[int(d)].projection(X[:1])[0])
        angles.append(_angle(vecs[:, 0], plane))  # the learnt normal: N's null direction
    return data, angles


@pytest.mark.parametrize("version", ["v5", "v7.3"])
def test_bar_lwr_wipe_mat_task_space_ranges_per_demo(tmp_path, capsys, lwr_log, version):
    cells = proc_data(lwr_log, seed=3)
    if version == "v5":
        save_cells_v5(tmp_path / "wipe.mat", cells)
    else:
        write_mat73(tmp_path / "wipe.mat", {"proc_data": Cell(cells)})
    data_cfg = {"files": [str(tmp_path / "wipe.mat")],
                "state": {"variable": "proc_data.X", "samples": "columns", "columns": [0, 1, 2]},
                "time": {"variable": "proc_data.dt"}, "demos": {"ranges": wipe_ranges(lwr_log)}}
    data, angles = _learn_and_compare(tmp_path, capsys, data_cfg, "task")
    assert max(angles) < 8.0, angles
    # and every wipe lies on the simulated table
    assert all(_angle(np.linalg.svd(data.X[data.demo == d] - data.X[data.demo == d].mean(0))[2][-1],
                      lwr_log.normal) < 2.0 for d in data.demo_ids)


def test_bar_lwr_wipe_mat_joints_forward_kinematics(tmp_path, capsys, lwr_log):
    cells = proc_data(lwr_log, seed=3)
    save_cells_v5(tmp_path / "wipe.mat", cells)
    (tmp_path / "LWR.urdf").write_text(LWR4.urdf())
    data_cfg = {"files": [str(tmp_path / "wipe.mat")],
                "state": {"variable": "proc_data.J", "samples": "columns",
                          "forward_kinematics": {"robot": "LWR.urdf", "frame": "flange"}},
                "time": {"variable": "proc_data.dt"}, "demos": {"ranges": wipe_ranges(lwr_log)}}
    data, angles = _learn_and_compare(tmp_path, capsys, data_cfg, "joints")
    assert max(angles) < 8.0, angles
    assert data.state_names == ["x", "y", "z"] and data.state_units == ["m"] * 3
    # FK of the joints is the pose stored in X (rows 0..2), sample by sample
    task = load_demonstrations({**data_cfg, "state": {"variable": "proc_data.X", "samples": "columns",
                                                      "columns": [0, 1, 2]}})
    np.testing.assert_allclose(data.X, task.X, atol=1e-12)


def test_shipped_lwr_wipe_configs(tmp_path, capsys):
    """configs/lwr_wipe_{mat,fk,joints}.yaml on sample_data/lwr_wipe.mat (the tutorial
    docs/tutorials/kuka_wipe.md): six wipes from labelled ranges and from the force cut, each
    learnt normal within 1° of its wipe's plane; in joint space, A(q) ∥ nᵀJ_p(q) for the normal
    of the plane of all wipes."""
    from pathlib import Path

    root = Path(__file__).resolve().parent.parent
    normals = {}
    for name in ("lwr_wipe_mat", "lwr_wipe_fk"):
        cfg = root / "configs" / f"{name}.yaml"
        out = tmp_path / name
        assert main(["run", str(cfg), "-o", str(out), "--json", "-q"]) == 0
        summary = json.loads(capsys.readouterr().out)
        assert summary["stages"]["learn-a"]["n_constraints"] == 1
        model, _ = load_model(out / "model.h5")
        data = load_demonstrations(yaml.safe_load(cfg.read_text())["data"], base=cfg.parent)
        assert data.n_demos == 6
        for d in model.models_:
            X = data.X[data.demo == d]
            plane = np.linalg.svd(X - X.mean(0))[2][-1]
            normals[(name, d)] = np.linalg.eigh(model.models_[d].projection(X[:1])[0])[1][:, 0]
            assert _angle(normals[(name, d)], plane) < 1.0
    assert all(_angle(normals[("lwr_wipe_mat", d)], normals[("lwr_wipe_fk", d)]) < 0.1
               for _, d in normals)
    cfg = root / "configs" / "lwr_wipe_joints.yaml"
    assert main(["run", str(cfg), "-o", str(tmp_path / "joints"), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["stages"]["learn-a"]["test"]["NPOE"] < 1e-3
    model, _ = load_model(tmp_path / "joints" / "model.h5")
    data = load_demonstrations(yaml.safe_load(cfg.read_text())["data"], base=cfg.parent)
    chain = LWR4.chain()
    P = chain.forward(data.X).position
    table = np.linalg.svd(P - P.mean(0))[2][-1]  # every wipe on one table
    A = model.constraint(data.X)[:, 0, :]
    truth = np.einsum("i,nij->nj", table, chain.jacobian(data.X, rows=[0, 1, 2]))
    assert max(_angle(a, b) for a, b in zip(A[::50], truth[::50], strict=True)) < 1.0
