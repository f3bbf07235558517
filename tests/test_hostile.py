"""Hostile and broken inputs (issue 8): never crash, never hang, never read outside the
file, never lose data. Every fixture is written at test time by the real writers
(h5py, our own save_model / write_demonstrations); no bytes are typed by hand."""

from __future__ import annotations

import json
import os
import time
from pathlib import Path

import h5py
import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import h5safe
from ccl_cli.io.hdf5 import read_demonstrations, write_demonstrations
from ccl_cli.models import load_model


def run_main(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def one_line_error(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip()]
    assert len(lines) == 1 and lines[0].startswith("ccl: error: "), err
    assert "internal error" not in err and "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    """A data file and a learnt null-space model (learn-v), both written by ccl."""
    root = tmp_path_factory.mktemp("hostile")
    data = root / "toy.h5"
    write_demonstrations(data, sim.toy2d(n_demos=4, n_steps=40, seed=0))
    assert main(["learn-v", str(data), "-o", str(root / "v"), "-q", "--n-centres", "4",
                 "--test-fraction", "0"]) == 0  # 4 demonstrations: too few for a held-out set
    return {"root": root, "data": data, "model": root / "v" / "model.h5"}


def copy(src: Path, dst: Path) -> Path:
    dst.write_bytes(src.read_bytes())
    return dst


# -- HDF5 is data ----------------------------------------------------------------------------
def fifo(tmp_path: Path) -> Path:
    """A named pipe: reading it would block forever, so a test that finishes proves
    nothing read it."""
    path = tmp_path / "secret.fifo"
    os.mkfifo(path)
    return path


def external_storage(path: Path, name: str, target: Path) -> None:
    with h5py.File(path, "a") as f:
        shape, dtype = f[name].shape, f[name].dtype
        del f[name]
        f.create_dataset(name, shape=shape, dtype=dtype,
                         external=[(str(target), 0, int(np.prod(shape)) * dtype.itemsize)])


def external_link(path: Path, name: str, target: Path) -> None:
    with h5py.File(target, "w") as g:
        g["x"] = np.ones((3, 3))
    with h5py.File(path, "a") as f:
        del f[name]
        f[name] = h5py.ExternalLink(str(target), "/x")


def virtual(path: Path, name: str, target: Path) -> None:
    with h5py.File(path, "a") as f:
        shape = f[name].shape
        with h5py.File(target, "w") as g:
            g["x"] = np.ones(shape)
        layout = h5py.VirtualLayout(shape=shape, dtype="f8")
        layout[...] = h5py.VirtualSource(str(target), "x", shape=shape)
        del f[name]
        f.create_virtual_dataset(name, layout)


@pytest.mark.parametrize("kind", ["storage", "link", "virtual"])
@pytest.mark.parametrize("which", ["model", "data"])
def test_hdf5_never_reads_another_file(capsys, fixtures, tmp_path, kind, which):
    model = copy(fixtures["model"], tmp_path / "model.h5")
    data = copy(fixtures["data"], tmp_path / "data.h5")
    target = fifo(tmp_path) if kind == "storage" else tmp_path / "other.h5"
    name = "arrays/W_" if which == "model" else "demos/demo_0001/x"
    {"storage": external_storage, "link": external_link, "virtual": virtual}[kind](
        model if which == "model" else data, name, target)
    t0 = time.perf_counter()
    code, _, err = run_main(capsys, "predict", model, data, "-o", tmp_path / "p.csv")
    assert code == 2 and time.perf_counter() - t0 < 20
    line = one_line_error(err)
    assert name in line and ("external" in line or "virtual" in line) and "outside the file" in line
    assert not (tmp_path / "p.csv").exists()


def test_dangling_soft_link_is_refused(fixtures, tmp_path):
    data = copy(fixtures["data"], tmp_path / "data.h5")
    with h5py.File(data, "a") as f:
        del f["demos/demo_0000/x"]
        f["demos/demo_0000/x"] = h5py.SoftLink("/nowhere")
    with pytest.raises(h5safe.InputError, match="soft link to /nowhere"):
        read_demonstrations(data)


@pytest.mark.parametrize("bad", [np.nan, np.inf, 1e308])
def test_non_finite_or_overflowing_weights_are_refused(capsys, fixtures, tmp_path, bad):
    model = copy(fixtures["model"], tmp_path / "model.h5")
    with h5py.File(model, "a") as f:
        f["arrays/W_"][0, 0] = bad
    code, _, err = run_main(capsys, "predict", model, fixtures["data"], "-o", tmp_path / "p.csv")
    assert code == 2, err
    if np.isfinite(bad):  # finite, but predictions would overflow
        assert "W_ holds values beyond" in one_line_error(err)
    else:
        assert "W_ contains NaN or inf" in one_line_error(err)
    assert not (tmp_path / "p.csv").exists()


@pytest.mark.parametrize("value", ["1.0", np.array([1, 1]), 1.0, True])
@pytest.mark.parametrize("which", ["model", "data"])
def test_version_attribute_of_the_wrong_type(capsys, fixtures, tmp_path, which, value):
    path = copy(fixtures[which], tmp_path / f"{which}.h5")
    key = "schema_version" if which == "model" else "format_version"
    with h5py.File(path, "a") as f:
        f.attrs[key] = value
    with pytest.raises(h5safe.InputError, match=f"attribute '{key}' must be an integer"):
        load_model(path) if which == "model" else read_demonstrations(path)


@pytest.mark.parametrize("edit", ["string_x", "x_3d", "scalar_t", "demos_dataset", "index_str",
                                  "mask_numbers", "names_int", "sigma2_str", "params_list", "kind_arr"])
def test_hdf5_structure_is_typed(fixtures, tmp_path, edit):
    which = "model" if edit in ("sigma2_str", "params_list", "kind_arr") else "data"
    path = copy(fixtures[which], tmp_path / "f.h5")
    with h5py.File(path, "a") as f:
        if edit == "string_x":
            del f["demos/demo_0000/x"]
            f["demos/demo_0000/x"] = np.array(["a", "b"], dtype=h5py.string_dtype())
        elif edit == "x_3d":
            x = f["demos/demo_0000/x"][()]
            del f["demos/demo_0000/x"]
            f["demos/demo_0000/x"] = x[:, :, None]
        elif edit == "scalar_t":
            del f["demos/demo_0000/t"]
            f["demos/demo_0000/t"] = 1.0
        elif edit == "demos_dataset":
            del f["demos"]
            f["demos"] = np.zeros(3)
        elif edit == "index_str":
            f["demos/demo_0000"].attrs["index"] = "0"
        elif edit == "mask_numbers":
            f["mask/train"] = np.arange(3)
        elif edit == "names_int":
            f.attrs["state_names"] = np.arange(2)
        elif edit == "sigma2_str":
            f["basis"].attrs["sigma2"] = "wide"
        elif edit == "params_list":
            f.attrs["params"] = "[1, 2]"
        elif edit == "kind_arr":
            f.attrs["kind"] = np.array([1, 2])
    with pytest.raises(h5safe.InputError) as info:
        load_model(path) if which == "model" else read_demonstrations(path)
    assert str(path) in info.value.message and "\n" not in info.value.message


def test_files_ccl_writes_are_sealed_and_edits_are_probed(fixtures, tmp_path):
    assert h5safe.sealed(fixtures["data"]) and h5safe.sealed(fixtures["model"])
    with h5py.File(fixtures["model"]) as f:  # still plain HDF5 for every other tool
        assert f.attrs["format"] == "ccl-model"
    edited = copy(fixtures["data"], tmp_path / "edited.h5")
    with h5py.File(edited, "a") as f:
        f.attrs["frame_id"] = "edited"
    assert not h5safe.sealed(edited)  # the hash no longer matches: parsed in a child first
    data, _ = read_demonstrations(edited)
    assert data.n_demos == 4


def test_libhdf5_hang_is_bounded(fixtures, tmp_path, monkeypatch):
    """A file libhdf5 never finishes parsing is refused after the time limit: the
    child process stands in for libhdf5 by sleeping."""
    edited = copy(fixtures["data"], tmp_path / "hangs.h5")
    with h5py.File(edited, "a") as f:
        f.attrs["frame_id"] = "edited"

    def sleeps(path, cpu_limit):
        time.sleep(60)

    def spins(path, cpu_limit):
        import resource

        resource.setrlimit(resource.RLIMIT_CPU, (1, 2))
        while True:
            pass

    monkeypatch.setattr(h5safe, "_probe_child", sleeps)
    monkeypatch.setattr(h5safe.threading, "active_count", lambda: 1)  # fork even if a test left threads
    t0 = time.perf_counter()
    with pytest.raises(h5safe.InputError, match="did not finish parsing the file within 0.5 s"):
        h5safe.open_hdf5(edited, timeout=0.5)
    assert time.perf_counter() - t0 < 5
    monkeypatch.setattr(h5safe, "_probe_child", spins)  # the measured hangs are CPU-bound loops
    with pytest.raises(h5safe.InputError, match="within 5 s of CPU time"):
        h5safe.open_hdf5(edited)


def test_libhdf5_crash_is_contained(fixtures, tmp_path, monkeypatch):
    edited = copy(fixtures["data"], tmp_path / "crashes.h5")
    with h5py.File(edited, "a") as f:
        f.attrs["frame_id"] = "edited"
    monkeypatch.setattr(h5safe, "_probe_child", lambda path, cpu_limit: os.kill(os.getpid(), 11))
    monkeypatch.setattr(h5safe.threading, "active_count", lambda: 1)
    with pytest.raises(h5safe.InputError, match="crashed parsing the file"):
        h5safe.open_hdf5(edited)


def test_model_json_attributes_are_typed(fixtures, tmp_path):
    model = copy(fixtures["model"], tmp_path / "m.h5")
    with h5py.File(model, "a") as f:
        params = json.loads(f.attrs["params"])
        params["n_centres"] = "many"
        f.attrs["params"] = json.dumps(params)
    with pytest.raises(h5safe.InputError, match="parameter 'n_centres' must be int"):
        load_model(model)
    with h5py.File(model, "a") as f:
        params["n_centres"] = 4
        f.attrs["params"] = json.dumps(params)
        f.attrs["fitted"] = json.dumps({"n_action_": 2.5})
    with pytest.raises(h5safe.InputError, match="n_action_ must be an integer"):
        load_model(model)
    with h5py.File(model, "a") as f:
        f.attrs["fitted"] = "[" * 100_000
    with pytest.raises(h5safe.InputError, match="not valid JSON"):
        load_model(model)
