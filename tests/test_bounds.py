"""Bounded reads (issue 20): declared sizes checked before anything is allocated, only
regular files opened, paths named by a bag stay in its folder, the HDF5 probe fails
closed, and library exceptions met at their source. Every fixture is written at test
time by the real writers (h5py, scipy.io.savemat, rosbags, mcap); a test that finishes
proves that nothing blocked on a FIFO."""

from __future__ import annotations

import json
import logging
import os
import struct
import subprocess
import sys
from pathlib import Path

import h5py
import numpy as np
import pytest
import scipy.io
import scipy.sparse
import writers
from tests_paths import cpu_seconds

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io import limits, load_demonstrations, write_demonstrations
from ccl_cli.io.formats import mat5_elements
from ccl_cli.io.h5 import probe as h5probe
from ccl_cli.io.limits import check_claim, max_bytes

JOINTS = {"topic": "/joint_states", "field": "position", "joints": writers.JOINTS[:3]}


def refused(cfg: dict, match: str) -> str:
    with pytest.raises(InputError, match=match) as info:
        load_demonstrations(cfg)
    assert "\n" not in info.value.message
    return info.value.message


# -- the cap -------------------------------------------------------------------------------------
def test_cap_is_configurable_and_counts_bytes_exactly(monkeypatch):
    monkeypatch.delenv("CCL_MAX_BYTES", raising=False)
    assert max_bytes() == 2 << 30
    monkeypatch.setenv("CCL_MAX_BYTES", "512M")
    assert max_bytes() == 512 << 20
    assert check_claim("f", "x", (1 << 20, 64)) == 512 << 20  # exactly the cap: allowed
    with pytest.raises(InputError, match=r"x declares 1048577×64 \(512 MiB\), over the cap of 512 MiB"):
        check_claim("f", "x", (1 << 20 | 1, 64))
    with pytest.raises(InputError, match="far more than the file holds"):
        check_claim("f", "x", (10_000_000, 2), 8, file_bytes=1000)  # 160 MB from 1 kB
    monkeypatch.setenv("CCL_MAX_BYTES", "lots")
    with pytest.raises(InputError, match="CCL_MAX_BYTES='lots'"):
        max_bytes()


def test_mat73_declaring_a_billion_doubles_is_refused_before_reading(tmp_path):
    path = writers.write_mat73(tmp_path / "bomb.mat", {"U": [[1.0, 2.0]]})
    with h5py.File(path, "a") as f:  # declared, never written: the file stays a few kB
        ds = f.create_dataset("X", shape=(1_000_000_000, 1), dtype="f8", chunks=(1 << 16, 1))
        ds.attrs["MATLAB_class"] = b"double"
    assert path.stat().st_size < 20_000
    t0 = cpu_seconds()
    refused({"files": [str(path)], "state": {"variable": "X"}, "time": {"rate": 10}},
            r"X: the variable declares 1000000000×1 \(7.45 GiB\), over the cap")
    assert cpu_seconds() - t0 < 5  # nothing was allocated or read


def test_inspect_of_a_mat73_attribute_of_the_wrong_type_is_one_line(capsys, tmp_path):
    """A refusal inside libhdf5's visit callback is returned, not raised through it (h5py
    turned it into a SystemError: an internal error)."""
    path = writers.write_mat73(tmp_path / "a.mat", {"X": np.eye(2), "U": np.ones((1, 2))})
    assert main(["inspect", str(path), "--json"]) == 0
    assert {e["path"]: e["class"] for e in json.loads(capsys.readouterr().out)["tree"]}["U"] == "double"
    with h5py.File(path, "r+") as f:
        f["U"].attrs["MATLAB_class"] = np.array([1, 2])
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == f"ccl: error: {path}:/U: attribute 'MATLAB_class' must be a string, got an array int64 " \
                  "(2,)\n"


def test_mat73_cells_are_bounded_too(tmp_path):
    arm = sim.arm7(seed=0, n_demos=2, n_steps=10)
    path = writers.write_mat73(tmp_path / "c.mat", {"X": [arm.X[arm.demo == d].T for d in arm.demo_ids]})
    with h5py.File(path, "a") as f:  # the second cell's target replaced by a bomb
        target = f[f["X"][()].ravel()[1]].name
        del f[target]
        ds = f.create_dataset(target, shape=(400_000_000, 7), dtype="f8", chunks=(1 << 16, 7))
        ds.attrs["MATLAB_class"] = b"double"
    refused({"files": [str(path)], "state": {"variable": "X", "samples": "columns"}, "time": {"rate": 10}},
            r"X\{2\}: the variable declares 400000000×7")


def test_sparse_mat_reads_as_dense_and_a_huge_one_is_refused(tmp_path):
    arm = sim.arm7(seed=1, n_demos=1, n_steps=30)
    small = tmp_path / "small.mat"
    scipy.io.savemat(small, {"X": scipy.sparse.csc_matrix(arm.X.T), "U": arm.U.T})
    data = load_demonstrations({"files": [str(small)], "state": {"variable": "X", "samples": "columns"},
                                "action": {"variable": "U", "samples": "columns"}, "time": {"rate": 10}})
    np.testing.assert_array_equal(data.X, arm.X)
    n = 1_000_000
    huge = tmp_path / "huge.mat"
    scipy.io.savemat(huge, {"X": scipy.sparse.csc_matrix((np.ones(3), ([0, 1, 2], [0, 1, 2])), shape=(n, n))})
    refused({"files": [str(huge)], "state": {"variable": "X"}, "time": {"rate": 10}},
            r"X: the sparse variable declares 1000000×1000000 \(7.28 TiB\)")
    cell = tmp_path / "cell.mat"  # inside a cell: checked before toarray
    m = scipy.sparse.csc_matrix((np.ones(1), ([0], [0])), shape=(100_000_000, 7))
    scipy.io.savemat(cell, {"X": np.array([m], dtype=object).reshape(1, 1)})
    refused({"files": [str(cell)], "state": {"variable": "X"}, "time": {"rate": 10}},
            r"the sparse matrix declares 100000000×7")


def test_compressed_mat_variable_inflating_past_its_shape_is_refused(tmp_path, monkeypatch):
    """A v7 variable is a zlib stream: scipy inflates its data tags whatever the header
    declares. The stream is counted (in 1 MB pieces) against what the declared shape holds."""
    arm = sim.arm7(seed=2, n_demos=1, n_steps=40)
    path = tmp_path / "z.mat"
    scipy.io.savemat(path, {"X": arm.X.T, "U": arm.U.T}, do_compression=True)
    cfg = {"files": [str(path)], "state": {"variable": "X", "samples": "columns"},
           "action": {"variable": "U", "samples": "columns"}, "time": {"rate": 10}}
    np.testing.assert_array_equal(load_demonstrations(cfg).X, arm.X)  # compressed files still read
    assert mat5_elements.inflated_size(path, "X", 1 << 20) > arm.X.nbytes
    writers.pad_compressed_mat(path, "X", 300 << 20)  # 300 MB of zeros behind a 7×40 header
    assert path.stat().st_size < 1 << 20
    assert mat5_elements.inflated_size(path, "X", 1 << 20) > 1 << 20  # counted up to the limit only
    refused(cfg, r"z.mat: X: the compressed variable inflates to more than \d+ bytes, more than its "
                 r"declared 7×40 can hold")
    struct_file = tmp_path / "s.mat"  # a struct's shape bounds nothing: the cap does
    scipy.io.savemat(struct_file, {"S": {"X": np.zeros((7, 40_000))}}, do_compression=True)
    monkeypatch.setenv("CCL_MAX_BYTES", "1M")
    refused({"files": [str(struct_file)], "state": {"variable": "S.X"}, "time": {"rate": 10}},
            r"S: the compressed variable inflates to more than 1048576 bytes")


@pytest.mark.parametrize("compressed", [False, True])
def test_mat_element_walk_passes_what_scipy_writes(tmp_path, compressed):
    """Every kind of variable scipy writes passes the element walk, compressed or not."""
    values = {"d": np.arange(12.0).reshape(3, 4), "c": np.array([[1 + 2j, 3]]), "i": np.int16([[1, -2]]),
              "b": np.array([[True, False]]), "s": "text é", "e": np.zeros((0, 3)),
              "sp": scipy.sparse.csc_matrix(np.eye(4)), "cell": np.array([[np.ones(2), "a"]], dtype=object),
              "st": {"a": np.ones((2, 2)), "b": {"c": np.arange(3.0)}}}
    path = tmp_path / "all.mat"
    scipy.io.savemat(path, values, do_compression=compressed)
    for name, shape, cls in scipy.io.whosmat(path):
        mat5_elements.check_variable(path, name, shape, cls in ("cell", "struct"), 1 << 30)


@pytest.mark.parametrize("bad_type", [8, 10, 521])
def test_mat_element_of_an_unknown_type_is_refused_not_a_crash(tmp_path, bad_type):
    """One flipped byte in a data element's type made scipy's reader crash the process
    (SIGSEGV); the element walk refuses it in one line (run in a child: a crash is a fail)."""
    arm = sim.arm7(seed=3, n_demos=1, n_steps=20)
    path = tmp_path / "t.mat"
    scipy.io.savemat(path, {"X": arm.X.T, "U": arm.U.T})
    raw = bytearray(path.read_bytes())
    at = raw.index(struct.pack("<II", 9, arm.U.nbytes), raw.index(b"U\0\0\0"))  # U's real part
    raw[at:at + 4] = struct.pack("<I", bad_type)
    path.write_bytes(bytes(raw))
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {state: {variable: X, samples: columns}, action: {variable: U, samples: columns}, "
                   "time: {rate: 10}}\n")
    proc = subprocess.run([sys.executable, "-m", "ccl_cli.cli", "inspect", str(path), "-c", str(cfg), "-q"],
                          capture_output=True, text=True, timeout=120)
    assert proc.returncode == 2, proc.stderr
    assert proc.stderr.strip() == (f"ccl: error: {path}: U: an element of type {bad_type}, which MATLAB "
                                   "files do not have; refused before reading (a damaged file)")


def test_foreign_hdf5_dataset_declaring_more_than_the_file_holds(tmp_path):
    path = tmp_path / "f.h5"
    with h5py.File(path, "w") as f:
        f.create_dataset("x", shape=(10_000_000, 3), dtype="f4", chunks=(1 << 16, 3))
        f["u"] = np.zeros((10, 3))
    refused({"files": [str(path)], "format": "hdf5", "state": {"dataset": "x"}, "action": {"dataset": "u"},
             "time": {"rate": 10}}, r"/x: the dataset declares 10000000×3 .*far more than the file holds")


def test_csv_line_over_the_cap_is_refused_without_reading_it(tmp_path, monkeypatch):
    monkeypatch.setenv("CCL_MAX_BYTES", "1M")
    cfg = {"state": {"columns": ["x"]}, "time": {"rate": 10}}
    good = tmp_path / "good.csv"
    good.write_text("x\n" + "\n".join(f"{v:.6f}" for v in np.linspace(0, 1, 2000)) + "\n")
    np.testing.assert_allclose(load_demonstrations({**cfg, "files": [str(good)]}).X[:, 0],
                               np.linspace(0, 1, 2000), atol=1e-6)
    one_line = tmp_path / "one.csv"
    one_line.write_bytes(b"x," + b"1.0," * 300_000)  # 1.2 MB, no line end
    refused({**cfg, "files": [str(one_line)]}, r"the text declares 1200002 bytes \(1.14 MiB\), over the cap")
    monkeypatch.delenv("CCL_MAX_BYTES")
    monkeypatch.setattr(limits, "MAX_LINE_BYTES", 1 << 20)  # lines of 1 MiB at most, files of 2 GiB
    rows = "".join(f"{k} {k + 1} {k + 2}\n" for k in range(200_000))  # 3.9 MB of short lines
    matrix = tmp_path / "m.txt"
    matrix.write_text(rows)
    data = load_demonstrations({"files": [str(matrix)], "state": {"columns": [0, 1, 2]},
                                "time": {"rate": 10}})
    np.testing.assert_array_equal(data.X[-1], [199_999, 200_000, 200_001])
    long = tmp_path / "long.txt"
    long.write_text(rows[:2_000_000] + "7 " * 600_000 + "\n" + rows[2_000_000:])
    refused({"files": [str(long)], "state": {"columns": [0]}, "time": {"rate": 10}},
            r"a line longer than 1048576 bytes starts at byte")
    cr = tmp_path / "cr.csv"  # old Mac line ends are line ends
    cr.write_bytes(b"x\r" + b"\r".join(b"%d" % i for i in range(200_000)) + b"\r")
    assert load_demonstrations({**cfg, "files": [str(cr)]}).n_samples == 200_000


# -- regular files only ---------------------------------------------------------------------------
def fifo(path: Path) -> Path:
    os.mkfifo(path)
    return path


@pytest.mark.parametrize("suffix", [".csv", ".h5", ".mat", ".bag", ".mcap", ".txt"])
def test_a_fifo_given_as_a_recording_is_refused(tmp_path, suffix):
    refused({"files": [str(fifo(tmp_path / f"rec{suffix}"))]}, "is a FIFO, not a regular file")


@pytest.mark.parametrize("fmt,state", [("csv", {"columns": ["x"]}), ("hdf5", None),
                                       ("mat", {"variable": "X"}), ("mcap", {"topic": "/a"}),
                                       ("bag", {"topic": "/a"})])
def test_a_fifo_with_an_explicit_format_is_refused(tmp_path, fmt, state):
    path = fifo(tmp_path / "rec.dat")
    refused({"files": [str(path)], "format": fmt, "state": state, "time": {"rate": 10}}, "is a FIFO")


@pytest.mark.parametrize("storage", ["sqlite3", "mcap"])
def test_fifos_named_by_a_ros2_bag_are_refused(tmp_path, storage):
    rec = writers.joint_recording(n=30)
    bag = writers.write_ros2_bag(tmp_path / "bag", rec, storage)
    store = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
    store.unlink()
    fifo(store)
    refused({"files": [str(bag)], "state": JOINTS}, "a storage file of the bag is a FIFO")
    meta = bag / "metadata.yaml"
    meta.unlink()
    fifo(meta)
    refused({"files": [str(bag)], "state": JOINTS}, "metadata.yaml: .* is a FIFO")


def test_fifo_config_and_model_are_one_line(capsys, tmp_path):
    data = tmp_path / "toy.h5"
    write_demonstrations(data, sim.toy2d(n_demos=3, n_steps=20, seed=0))
    assert main(["learn-a", str(data), "-c", str(fifo(tmp_path / "c.yaml")), "-o", str(tmp_path / "o"),
                 "-q"]) == 2
    assert "c.yaml: the config is a FIFO" in capsys.readouterr().err
    assert main(["predict", str(fifo(tmp_path / "m.h5")), str(data), "-o", str(tmp_path / "p.csv")]) == 2
    assert "FIFO" in capsys.readouterr().err
    with pytest.raises(ConfigError, match="manifest is a FIFO"):
        from ccl_cli.app.batch import plan

        plan(fifo(tmp_path / "m.yaml"))


def test_inspect_refuses_fifos_and_reads_bag_folders(capsys, tmp_path):
    """``ccl inspect`` first asks whether its input is a model file: a FIFO (or a symlink to
    one) is refused without being opened, a ROS 2 bag folder is not a model and is read."""
    pipe = fifo(tmp_path / "m.h5")
    (tmp_path / "link.h5").symlink_to(pipe)
    for path in (pipe, tmp_path / "link.h5"):
        assert main(["inspect", str(path)]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "is a FIFO, not a regular file" in err
    rec = writers.joint_recording(n=30)
    bag = writers.write_ros2_bag(tmp_path / "bag", rec, "sqlite3")
    assert main(["inspect", str(bag), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["topics"]["/joint_states"]["count"] == 30


# -- paths named by a bag ------------------------------------------------------------------------
def test_bag_storage_outside_its_folder_needs_allow_outside(tmp_path, caplog):
    rec = writers.joint_recording(n=40)
    elsewhere = writers.write_ros2_bag(tmp_path / "elsewhere", rec, "sqlite3")
    reference = load_demonstrations({"files": [str(elsewhere)], "state": JOINTS})
    bag = tmp_path / "bag"
    bag.mkdir()
    (bag / "metadata.yaml").write_bytes((elsewhere / "metadata.yaml").read_bytes())
    store = next(p for p in elsewhere.iterdir() if p.suffix == ".db3")
    (bag / store.name).symlink_to(store)  # a symlink inside the bag to a bag elsewhere
    cfg = {"files": [str(bag)], "state": JOINTS}
    refused(cfg, f"leads through a symlink to {store}, outside .*data.allow_outside: true allows it")
    with caplog.at_level(logging.WARNING, logger="ccl"):
        data = load_demonstrations({**cfg, "allow_outside": True})
    np.testing.assert_array_equal(data.X, reference.X)
    assert "outside the bag (followed" in caplog.text
    text = (bag / "metadata.yaml").read_text().replace(f"- {store.name}", f"- ../elsewhere/{store.name}")
    (bag / "metadata.yaml").write_text(text)
    refused(cfg, rf"names '../elsewhere/{store.name}', which leads to {store}, outside")


def test_a_symlinked_metadata_yaml_leading_outside_the_bag_needs_allow_outside(tmp_path, capsys):
    """A ROS 2 bag whose metadata.yaml is a symlink to a file elsewhere: refused like a
    storage file outside the bag (it was followed silently), read with data.allow_outside."""
    rec = writers.joint_recording(n=40)
    bag = writers.write_ros2_bag(tmp_path / "bag", rec, "sqlite3")
    reference = load_demonstrations({"files": [str(bag)], "state": JOINTS})
    outside = tmp_path / "meta.yaml"
    outside.write_bytes((bag / "metadata.yaml").read_bytes())
    (bag / "metadata.yaml").unlink()
    (bag / "metadata.yaml").symlink_to(outside)
    cfg = {"files": [str(bag)], "state": JOINTS}
    refused(cfg, f"leads through a symlink to {outside}, outside .*data.allow_outside: true allows it")
    assert main(["inspect", str(bag)]) == 2 and "outside" in capsys.readouterr().err
    data = load_demonstrations({**cfg, "allow_outside": True})
    np.testing.assert_array_equal(data.X, reference.X)


# -- the probe fails closed ----------------------------------------------------------------------
def test_probe_refuses_a_file_whose_attribute_table_cannot_be_read(tmp_path, monkeypatch):
    """libhdf5 failing while the probe iterates an attribute table (as on the damaged model
    of issue 20): the file is refused, and the parent reads no attribute of it by name."""
    path = tmp_path / "m.h5"
    with h5py.File(path, "w") as f:
        f.attrs["format"] = "ccl-model"
        f["x"] = np.ones(3)

    def damaged(self):
        raise OSError("Unable to iterate over attributes (bad local heap signature)")

    read_by_name: list[str] = []
    original = h5py.AttributeManager.__getitem__
    monkeypatch.setattr(h5py.AttributeManager, "__iter__", damaged)  # the fork inherits it
    monkeypatch.setattr(h5probe.threading, "active_count", lambda: 1)  # the fork, whatever ran before
    monkeypatch.setattr(h5py.AttributeManager, "__getitem__",
                        lambda self, key: read_by_name.append(key) or original(self, key))
    with pytest.raises(InputError, match=r"failed parsing the file \(OSError: Unable to iterate") as info:
        h5probe.open_hdf5(path, "model file")
    assert "\n" not in info.value.message and read_by_name == []


def test_damaged_model_is_refused_by_the_probe(capsys, tmp_path):
    """Models damaged next to attribute names until libhdf5 fails iterating an attribute
    table (the hang of issue 20: the probe let such files through): predict and inspect
    refuse them in one line."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import hostile_bars

    data = tmp_path / "toy.h5"
    write_demonstrations(data, sim.toy2d(n_demos=4, n_steps=30, seed=0))
    assert main(["learn-v", str(data), "-o", str(tmp_path / "v"), "-q", "--n-centres", "4",
                 "--test-fraction", "0"]) == 0
    found = hostile_bars.damaged_models(tmp_path, tmp_path / "v" / "model.h5", n=1, tries=400)
    assert found, "the seeded search found no damaged attribute table"
    t0 = cpu_seconds()
    for argv in (["predict", found[0], data, "-o", tmp_path / "p.csv"], ["inspect", found[0]]):
        capsys.readouterr()
        assert main([str(a) for a in argv]) == 2
        err = capsys.readouterr().err
        assert err.count("\n") == 1 and "failed parsing the file" in err and "refused" in err, err
    assert cpu_seconds() - t0 < 10


def test_probe_child_exit_without_a_message_is_a_refusal(tmp_path, monkeypatch):
    path = tmp_path / "m.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.ones(3)
    monkeypatch.setattr(h5probe, "_probe_child", lambda p, cpu_limit: os._exit(7))
    monkeypatch.setattr(h5probe.threading, "active_count", lambda: 1)  # the fork, whatever ran before
    with pytest.raises(InputError, match=r"failed parsing the file \(exit 7"):
        h5probe.probe(path)


def test_foreign_attributes_are_checked(tmp_path):
    path = tmp_path / "f.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.ones((5, 2))
        f["x"].attrs["names"] = np.array([b"a", b"\xff\xfe"])  # not UTF-8
        f.attrs["format"] = np.array([1, 2])  # not a string
    refused({"files": [str(path)], "format": "hdf5", "state": {"dataset": "x"}, "time": {"rate": 10}},
            r"attribute 'names' must hold names")
    refused({"files": [str(path)], "format": "hdf5"}, r"attribute 'format' must be a string")


@pytest.mark.parametrize("suffix", [".h5", ".mat"])
def test_an_object_name_that_is_not_utf8_is_one_line(capsys, tmp_path, suffix):
    """h5py decodes link names as UTF-8 inside its visit callback and wraps the failure in a
    SystemError (fuzz classic seed 4280, a flipped byte in a MATLAB v7.3 name)."""
    path = writers.write_mat73(tmp_path / f"odd{suffix}", {"X": [[1.0, 2.0], [3.0, 4.0]]})
    with h5py.File(path, "a") as f:
        f.create_dataset(b"Y\xff\x80", data=np.ones(3))
    assert main(["inspect", str(path)]) == 2
    err = capsys.readouterr().err
    assert err == f"ccl: error: {path}: cannot read the HDF5 structure (an object's name is not UTF-8); " \
                  "damaged file?\n"


# -- JSON messages missing keys ------------------------------------------------------------------
@pytest.mark.parametrize("key,match", [
    ("name", r"a JointState needs name: a list of strings, got NoneType \(message 8\)"),
    ("position", r"field 'position' not found in /joint_states .* \(message 8\)"),
    ("header.stamp.sec", r"message 8 of /joint_states has no 'sec' \(header.stamp\)"),
    ("header.stamp", r"message 8 of /joint_states has no 'stamp' \(header.stamp\)"),
])
def test_json_mcap_message_missing_a_key_is_one_line(tmp_path, key, match):
    rec = writers.joint_recording(n=20)
    msgs = [writers.msg_dict(rec, i) for i in range(20)]
    *parents, last = key.split(".")
    obj = msgs[7]
    for p in parents:
        obj = obj[p]
    del obj[last]
    path = writers.write_mcap_json(tmp_path / "r.mcap", rec, msgs)
    refused({"files": [str(path)], "state": JOINTS}, match)
    msgs = [writers.msg_dict(rec, i) for i in range(20)]
    msgs[3]["velocity"] = {"a": 1}  # another type in a later message
    path = writers.write_mcap_json(tmp_path / "v.mcap", rec, msgs)
    refused({"files": [str(path)], "state": JOINTS, "action": {**JOINTS, "field": "velocity"}},
            "velocity")


def test_json_mcap_first_message_without_joint_names_is_one_line(tmp_path):
    """The joints configured and the first message naming none: one line (was a TypeError)."""
    rec = writers.joint_recording(n=20)
    msgs = [writers.msg_dict(rec, i) for i in range(20)]
    del msgs[0]["name"]
    path = writers.write_mcap_json(tmp_path / "r.mcap", rec, msgs)
    refused({"files": [str(path)], "state": JOINTS},
            r"r.mcap: /joint_states: a JointState needs name: a list of strings, got NoneType$")


# -- kinematic features ---------------------------------------------------------------------------
def test_arm_features_on_data_of_another_width_is_one_line(capsys, tmp_path):
    data = tmp_path / "three.h5"
    arm = sim.arm7(seed=0, n_demos=2, n_steps=20)
    write_demonstrations(data, Demonstrations(arm.X[:, :3], arm.U[:, :3], arm.demo, arm.t))
    code = main(["learn-a", str(data), "--method", "lambda", "--features", "arm7", "-o", str(tmp_path / "o"),
                 "-q", "--n-centres", "3"])
    err = [ln for ln in capsys.readouterr().err.splitlines() if not ln.startswith("ccl: warning")]
    assert code == 2 and len(err) == 1 and "features arm7 need the 7 joint angles of the arm per sample" in \
        err[0] and "got 3 columns" in err[0], err


def test_mat73_cells_that_are_not_references_or_loop_are_refused(tmp_path):
    arm = sim.arm7(seed=0, n_demos=2, n_steps=10)
    path = writers.write_mat73(tmp_path / "c.mat", {"X": [arm.X[arm.demo == d].T for d in arm.demo_ids]})
    cfg = {"files": [str(path)], "state": {"variable": "X", "samples": "columns"}, "time": {"rate": 10}}
    assert load_demonstrations(cfg).n_samples == 20  # as written
    with h5py.File(path, "a") as f:  # the cell's references replaced by bytes
        del f["X"]
        f["X"] = np.zeros((2, 1), dtype=np.uint8)
        f["X"].attrs["MATLAB_class"] = b"cell"
    refused(cfg, "a cell must hold object references, got uint8")
    with h5py.File(path, "a") as f:  # a cell whose only element is the cell itself
        del f["X"]
        ds = f.create_dataset("X", shape=(1, 1), dtype=h5py.ref_dtype)
        ds.attrs["MATLAB_class"] = b"cell"
        ds[0, 0] = ds.ref
    refused(cfg, "nested deeper than 32 levels")
    with h5py.File(path, "a") as f:  # a cell pointing to a named datatype (fuzz seed 280, case 5158)
        f["#refs#/type"] = np.dtype("f8")
        f["X"][0, 0] = f["#refs#/type"].ref
    refused(cfg, "a reference to a Datatype, not an array")
    assert main(["inspect", str(path), "--json"]) == 2


def test_attribute_text_that_is_not_utf8_is_refused_in_plain_text(capsys, tmp_path):
    """A MATLAB_class written as bytes that are not UTF-8 (h5py hands them back with
    surrogate escapes): one line that any terminal can print."""
    arm = sim.arm7(seed=0, n_demos=1, n_steps=10)
    path = writers.write_mat73(tmp_path / "c.mat", {"X": arm.X.T})
    with h5py.File(path, "a") as f:
        f["X"].attrs["MATLAB_class"] = b"\xff\xfe"
    code = main(["learn-a", str(path), "-o", str(tmp_path / "o"), "-c", str(_config(tmp_path)), "-q"])
    err = capsys.readouterr().err
    assert code == 2 and "MATLAB_class' must be" in err and err.count("\n") == 1, err
    err.encode("utf-8")  # no lone surrogate left in the message


def _config(tmp_path: Path) -> Path:
    cfg = tmp_path / "mat.yaml"
    cfg.write_text("data: {state: {variable: X, samples: columns}, time: {rate: 10}}\n"
                   "learn-a: {method: nhat}\n")
    return cfg


def test_probe_memory_is_bounded(tmp_path, monkeypatch):
    """What libhdf5 allocates while the probe parses a file is bounded (a damaged string or
    attribute table can make it claim gigabytes): over the bound, the file is refused."""
    path = tmp_path / "big.h5"
    with h5py.File(path, "w") as f:
        f["x"] = np.arange(5_000_000, dtype=np.float64)  # 40 MB, read by the probe
    # a fresh interpreter (the probe's other path): no memory this process freed to reuse
    monkeypatch.setattr(h5probe.threading, "active_count", lambda: 2)
    monkeypatch.setenv("CCL_HDF5_MEMORY_MB", "20")
    with pytest.raises(InputError, match="parsing the file needs more than 20 MiB of memory"):
        h5probe.probe(path)
    monkeypatch.setenv("CCL_HDF5_MEMORY_MB", "400")
    h5probe.probe(path)  # within the bound: parsed


def test_a_ros1_bag_whose_message_definition_does_not_parse_is_one_line(tmp_path, capsys):
    """The numpy path decodes one message with the bag's own definition: a definition that
    does not parse (a flipped byte in 'sensor_msgs') is the bag's fault, one line (it was
    rosbags' TypesysError as an internal error; fuzz seed 9201)."""
    from rosbags.rosbag1 import Writer
    from writers import MSG, _msg, _typestore, joint_recording

    from ccl_cli.cli import main

    rec = joint_recording(n=50)
    ts = _typestore(ros1=True)
    good = ts.generate_msgdef(MSG, ros_version=1)
    path = tmp_path / "a.bag"
    with Writer(path) as writer:
        conn = writer.add_connection("/joint_states", MSG, msgdef=good[0].replace("float64[] position",
                                                                                 "float64[ position", 1),
                                     md5sum=good[1])
        for i in range(len(rec.t_ns)):
            writer.write(conn, int(rec.log_ns[i]), ts.serialize_ros1(_msg(ts, rec, i), MSG))
    assert main(["inspect", str(path), "--json"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "cannot read the message definition of /joint_states" in err[0]


def test_a_hostile_mix_with_damaged_mcap_message_indexes_has_no_internal_error():
    """Message indexes pointing outside their chunk (case 6 of seed 9201: an IndexError in
    the numpy path): the library decodes such a file, or refuses it in one line."""
    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import fuzz

    result = fuzz.fuzz(cases=8, seed=9201, timeout=20.0, mix="hostile")
    assert {k: result["total"][k] for k in ("internal", "crash", "timeout")} == \
        {"internal": 0, "crash": 0, "timeout": 0}, result["internal_groups"]


def test_an_mcap_chunk_index_pointing_outside_the_file_is_one_line(tmp_path, capsys):
    """A damaged summary whose chunk index points past the end of the file (fuzz seed 9301:
    seek() raised OSError EINVAL, an internal error)."""
    import struct

    from mcap.reader import make_reader
    from writers import joint_recording, write_mcap_ros2

    from ccl_cli.cli import main

    path = write_mcap_ros2(tmp_path / "r.mcap", joint_recording(n=200))
    with open(path, "rb") as f:
        summary = make_reader(f).get_summary()
    start = summary.chunk_indexes[0].chunk_start_offset
    data = bytearray(path.read_bytes())
    record = data.rfind(b"\x08")  # the chunk index record: opcode, length, two times, then the offset
    while record > 0 and struct.unpack_from("<Q", data, record + 25)[0] != start:
        record = data.rfind(b"\x08", 0, record)
    assert record > 0
    struct.pack_into("<Q", data, record + 25, 2**53 + 34)
    path.write_bytes(bytes(data))
    assert main(["inspect", str(path), "--json"]) in (0, 2)
    capsys.readouterr()
    config = tmp_path / "c.yaml"
    config.write_text("data: {state: {topic: /joint_states, field: position}, action: {derive: state}}\n")
    assert main(["learn-a", str(path), "-c", str(config), "-o", str(tmp_path / "a"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "outside the file" in err[0], err


@pytest.mark.parametrize("field", ["chunk_pos", "index_pos"])
@pytest.mark.parametrize("kind", ["past-end", "beyond-seek", "max", "negative", "in-magic", "zero", "at-end"])
def test_a_ros1_bag_declaring_a_position_outside_the_file_is_one_line(tmp_path, capsys, field, kind):
    """A chunk or index position past the end of the bag, beyond any seek (≥ 2⁶³) or "negative"
    (an unsigned field near 2⁶⁴): checked before the seek (io/formats/bag1.py's _block raised
    ValueError / OSError EINVAL, an internal error: 16 of 20,000 fuzzed bags)."""
    import random

    sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))
    import fuzz

    from ccl_cli.io.formats.bag1 import read_index

    good = writers.write_ros1_bag(tmp_path / "good.bag", writers.joint_recording(n=60, gap_after=30))
    raw = good.read_bytes()
    rng = random.Random(0)
    for _ in range(200):  # the seeded draw that damages this field this way
        mutation, damaged = fuzz.ros1_positions(raw, rng)
        if mutation.startswith(f"ros1-position:{field}:{kind}"):
            break
    path = tmp_path / "damaged.bag"
    path.write_bytes(damaged)
    if kind != "at-end" or field == "index_pos":
        with pytest.raises(InputError) as info:  # the numpy index; then rosbags' reader says why
            read_index(path)
        assert "\n" not in info.value.message
    config = tmp_path / "c.yaml"
    config.write_text("data: {state: {topic: /joint_states, field: position}, action: {derive: state}}\n")
    for argv in (["inspect", str(path), "--json"],
                 ["learn-a", str(path), "-c", str(config), "-o", str(tmp_path / "a"), "-q"]):
        assert main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert len(err) == 1 and err[0].startswith("ccl: error: ") and "internal" not in err[0], err
