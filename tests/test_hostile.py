"""Hostile and broken inputs (issue 8): never crash, never hang, never read outside the
file, never lose data. Every fixture is written at test time by the real writers
(h5py, our own save_model / write_demonstrations); no bytes are typed by hand."""

from __future__ import annotations

import json
import os
import re
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from tests_paths import cpu_seconds

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import read_demonstrations, write_demonstrations
from ccl_cli.io.h5 import probe as h5safe
from ccl_cli.models import load_model


def run_main(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def one_line_error(err: str) -> str:
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("ccl: warning: ")]
    assert len(lines) == 1 and lines[0].startswith("ccl: error: "), err
    assert "internal error" not in err and "Traceback" not in err
    return lines[0]


@pytest.fixture(scope="module")
def fixtures(tmp_path_factory):
    """A data file and a learnt null-space model (learn-v), both written by ccl."""
    root = tmp_path_factory.mktemp("hostile")
    data = root / "toy.h5"
    # ≥ 5: no few-demos warning; version 1, whose per-demonstration objects the tests below damage
    write_demonstrations(data, sim.toy2d(n_demos=6, n_steps=40, seed=0), format_version=1)
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
    t0 = cpu_seconds()
    code, _, err = run_main(capsys, "predict", model, data, "-o", tmp_path / "p.csv")
    assert code == 2 and cpu_seconds() - t0 < 20
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
    if which == "data" and isinstance(value, str | float) and not isinstance(value, bool):
        # a version other writers store as text or a float names version 1: read as such
        expected, _ = read_demonstrations(fixtures["data"])
        got, _ = read_demonstrations(path)
        np.testing.assert_array_equal(got.X, expected.X)
        np.testing.assert_array_equal(got.demo, expected.demo)
        return
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
    assert data.n_demos == 6


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
    with pytest.raises(h5safe.InputError, match="did not finish parsing the file within 0.5 s"):
        h5safe.open_hdf5(edited, timeout=0.5)  # (had the timeout failed: the child's 60 s, then no error)
    monkeypatch.setattr(h5safe, "_probe_child", spins)  # the measured hangs are CPU-bound loops
    with pytest.raises(h5safe.InputError, match=f"within {h5safe.CPU_LIMIT} s of CPU time"):
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


@pytest.mark.parametrize("method,array", [("nhat", "eigenvalues_"), ("nhat", "residuals_"),
                                          ("linear", "scale_"), ("linear", "singular_values_")])
@pytest.mark.parametrize("edit", ["short", "long"])
def test_a_model_array_of_the_wrong_length_is_refused(capsys, tmp_path, method, array, edit):
    """The vectors a model keeps beside its weights, edited to another length: refused when
    the model loads (they were carried along silently)."""
    data = tmp_path / "toy.h5"
    write_demonstrations(data, sim.toy2d(constraint="parabola", n_demos=6, n_steps=40, seed=1))
    extra = ["--regressors", "polynomial", "--degree", "2"] if method == "linear" else []
    assert main(["learn-a", str(data), "--method", method, *extra, "-o", str(tmp_path / "m"), "-q",
                 "--test-fraction", "0"]) == 0
    model = tmp_path / "m" / "model.h5"
    load_model(model)
    with h5py.File(model, "a") as f:
        name = next(k for k in _datasets(f) if k.endswith(array))
        value = f[name][()]
        del f[name]
        f[name] = value[:-1] if edit == "short" else np.r_[value, value[-1:]]
    with pytest.raises(h5safe.InputError, match=f"array {array} has shape"):
        load_model(model)
    code, _, err = run_main(capsys, "predict", model, data, "-o", tmp_path / "p.csv")
    assert code == 2 and f"array {array} has shape" in one_line_error(err)


def _datasets(f) -> list[str]:
    found: list[str] = []
    f.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Dataset) else None)
    return found


# -- YAML safely -----------------------------------------------------------------------------
def billion_laughs(path: Path) -> Path:
    """Nine levels of nine aliases: 9^9 ≈ 387 million strings once expanded, in < 1 kB."""
    import yaml

    doc: dict = {"a0": ["lol"] * 9}
    text = yaml.safe_dump(doc)
    for i in range(1, 10):
        text = text.replace(f"a{i - 1}:", f"a{i - 1}: &a{i - 1}", 1)
        text += f"a{i}: [" + ", ".join([f"*a{i - 1}"] * 9) + "]\n"
    path.write_text(text.replace("a0:", "a0: &a0", 1) if "&a0" not in text else text)
    return path


def test_billion_laughs_is_refused_fast_and_small(capsys, tmp_path):
    import tracemalloc

    from ccl_cli import config as C

    bomb = billion_laughs(tmp_path / "bomb.yaml")
    assert bomb.stat().st_size < 1000
    tracemalloc.start()
    t0 = cpu_seconds()
    with pytest.raises(C.ConfigError, match="once aliases are expanded"):
        C.load(bomb)
    seconds = cpu_seconds() - t0
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert seconds < 1.0 and peak < 100e6
    code, _, err = run_main(capsys, "learn-a", "-c", bomb)
    assert code == 2 and "aliases" in one_line_error(err)


@pytest.mark.parametrize("case", ["deep_flow", "deep_block", "recursive", "not_utf8", "huge"])
def test_hostile_yaml_configs(capsys, tmp_path, case):
    path = tmp_path / "c.yaml"
    if case == "deep_flow":
        path.write_text("data: " + "[" * 20000 + "]" * 20000 + "\n")
        match = "nested deeper than 64"
    elif case == "deep_block":
        path.write_text("".join(" " * i + f"k{i}:\n" for i in range(2000)))
        match = "nested deeper than 64"
    elif case == "recursive":
        path.write_text("data: &a {files: *a}\n")
        match = "alias refers to its own parent"
    elif case == "not_utf8":
        path.write_bytes(b"seed: 1\ndata: {files: [caf" + "é".encode("latin-1") + b".h5]}\n")
        match = r"not UTF-8 text \(byte 26: 0xe9\)"
    else:
        path.write_text("seed: 1\n" + "#" * (17 << 20) + "\n")
        match = "larger than 16 MB"
    t0 = cpu_seconds()
    code, _, err = run_main(capsys, "learn-a", "-c", path)
    assert code == 2 and cpu_seconds() - t0 < 5
    import re

    assert re.search(match, one_line_error(err))


@pytest.mark.parametrize("text,match", [
    ("learn-a: {method: alpha, n_centres: 0}",
     "learn-a.n_centres must be an integer between 1 and 100000, got 0"),
    ("learn-pi: {basis: {kind: rbf, n_centres: -3}}",
     "learn-pi.basis.n_centres must be an integer between 1"),
    ("data: {action: {derive: state, order: 0}}", "data.action.order must be an integer between 1 and 20"),
    ("seed: -1", "seed must be an integer between 0"),
    ("learn-a: {tol: .nan}", "learn-a.tol must be a finite number"),
    ("stages: [{learn-v: {max_iter: 0}}]", "learn-v.max_iter must be an integer between 1"),
])
def test_config_numbers_in_range(capsys, tmp_path, text, match):
    path = tmp_path / "c.yaml"
    path.write_text(text + "\n")
    code, _, err = run_main(capsys, "learn-a", "-c", path)
    assert code == 2 and match in one_line_error(err)


# -- boundary cases of the readers ------------------------------------------------------------
@pytest.fixture()
def csv_rec(tmp_path):
    import sys

    sys.path.insert(0, str(Path(__file__).parent))
    import writers

    return writers.write_csv(tmp_path / "rec.csv", writers.joint_recording(n=40))


CSV_CFG = "data:\n  state: {columns: [x, y, z]}\n  time: {column: '%time', unit: UNIT}\n"


@pytest.mark.parametrize("case,match", [
    ("time_1e300", "time value '1e300' in row 4 is out of range"),
    ("time_inf", "time value 'inf' in row 4 is not finite"),
    ("time_huge_int", "in row 4 is out of range"),
    ("field_256k", "line 4: not a readable CSV row (field larger than field limit"),
    ("order_0", "derivative order must be an integer"),
    ("ranges_flat", "demos.ranges[0] must be [start, end]"),
    ("ranges_text", "demos.ranges[0] must be [start, end]"),
    ("delimiter", "time.delimiter must be one character"),
    ("format_mcap", "not an MCAP file"),
])
def test_reader_boundaries(capsys, tmp_path, csv_rec, case, match):
    lines = csv_rec.read_text().splitlines()
    cfg = CSV_CFG.replace("UNIT", "ns")
    first, rest = lines[3].split(",", 1)
    if case == "time_1e300":
        lines[3] = "1e300," + rest
    elif case == "time_inf":
        lines[3] = "inf," + rest
    elif case == "time_huge_int":
        lines[3] = "9" * 30 + "," + rest
    elif case == "field_256k":
        lines[3] = first + "," + "1" * 256_000 + "," + rest.split(",", 1)[1]
    elif case == "order_0":
        cfg += "  action: {derive: state, order: 0}\n"
    elif case == "ranges_flat":
        cfg += "  demos: {ranges: [0, 1]}\n"
    elif case == "ranges_text":
        cfg += "  demos: {ranges: [[a, b]]}\n"
    elif case == "delimiter":
        cfg = cfg.replace("unit: ns", "unit: ns, delimiter: ';;'")
    elif case == "format_mcap":
        cfg += "  format: mcap\n"
    csv_rec.write_text("\n".join(lines) + "\n")
    (tmp_path / "c.yaml").write_text(cfg)
    if case == "order_0":  # the config check comes first; the reader refuses it on its own too
        from ccl_cli.io.derivative import local_polynomial_derivative

        with pytest.raises(h5safe.InputError, match=match):
            local_polynomial_derivative(np.arange(5.0), np.ones((5, 1)), np.zeros(5, int), 3, 0)
        match = "order must be an integer between 1 and 20"
    code, _, err = run_main(capsys, "convert", csv_rec, "-c", tmp_path / "c.yaml", "-o", tmp_path / "o.h5")
    assert code == 2 and match in one_line_error(err)
    assert not (tmp_path / "o.h5").exists()


@pytest.mark.parametrize("edit", ["count_text", "topics_int", "duration_list", "storage_map", "deep",
                                  "paths_nested", "paths_none", "files_text"])
def test_ros2_metadata_with_odd_types(capsys, tmp_path, edit):
    import sys

    import yaml

    sys.path.insert(0, str(Path(__file__).parent))
    import writers

    bag = writers.write_ros2_bag(tmp_path / "bag", writers.joint_recording(n=20))
    meta_path = bag / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    if edit == "count_text":
        info["message_count"] = "many"
        info["topics_with_message_count"][0]["message_count"] = "many"
    elif edit == "topics_int":
        info["topics_with_message_count"] = 5
    elif edit == "duration_list":
        info["duration"] = [1, 2]
    elif edit == "storage_map":
        info["storage_identifier"] = {"a": 1}
    elif edit == "paths_nested":
        info["relative_file_paths"] = [["x"]]
    elif edit == "paths_none":
        info["relative_file_paths"] = [None]
    elif edit == "files_text":
        info["files"] = "x"
    meta_path.write_text(yaml.safe_dump(meta) if edit != "deep" else "a: " + "[" * 30000 + "]" * 30000)
    (tmp_path / "c.yaml").write_text("data:\n  state: {topic: /joint_states, field: position}\n")
    for command in (["inspect", bag], ["convert", bag, "-o", tmp_path / "o.h5"]):
        code, _, err = run_main(capsys, *command, "-c", tmp_path / "c.yaml")
        assert code in (0, 2), err
        if code == 2:
            one_line_error(err)
        if edit == "deep":  # refused by ccl's bounded YAML parser before rosbags sees it
            assert code == 2 and "nested deeper than 64 levels" in err
        if edit.startswith(("paths", "files")):  # the storage file names, checked before rosbags opens
            assert code == 2 and ("storage file name must be" in err or "must be lists" in err), err


WIDE = "9" * 5000  # over Python's 4,300-digit limit of int(str)


@pytest.mark.parametrize("where", ["config", "config_nested", "config_list", "manifest", "metadata",
                                   "model_params", "model_fitted", "job_record"])
def test_integers_beyond_64_bits_are_one_line(capsys, fixtures, tmp_path, where):
    """A 5,000-digit integer in a config, a manifest, a ROS 2 bag's metadata.yaml or a model's
    JSON attribute: exit 2, one line naming the file, the key and the line (it was an internal
    ValueError from int() of > 4,300 digits); refused at parse time, never converted."""
    import sys

    import yaml

    sys.path.insert(0, str(Path(__file__).parent))
    import writers

    cfg = tmp_path / "c.yaml"
    if where.startswith("config"):
        cfg.write_text({"config": f"seed: {WIDE}\n",
                        "config_nested": f"seed: 1\ndata:\n  test:\n    seed: {WIDE}\n",
                        "config_list": f"learn-a:\n  grid: {{n_centres: [1, -{WIDE}]}}\n"}[where])
        key = {"config": "seed", "config_nested": "data.test.seed",
               "config_list": "learn-a.grid.n_centres[1]"}[where]
        line = {"config": 1, "config_nested": 4, "config_list": 2}[where]
        code, _, err = run_main(capsys, "learn-a", fixtures["data"], "-c", cfg, "-o", tmp_path / "o")
        assert code == 2 and f"c.yaml:{line}: {key} is an integer of 5000 digits" in one_line_error(err)
    elif where == "manifest":
        manifest = tmp_path / "m.yaml"
        manifest.write_text(f"jobs:\n  - files: [x.h5]\n    overrides: {{seed: {WIDE}}}\n")
        code, _, err = run_main(capsys, "batch", manifest, "-o", tmp_path / "b")
        assert code == 2 and "m.yaml:3: jobs[0].overrides.seed is an integer of 5000 digits" \
            in one_line_error(err)
    elif where == "metadata":
        bag = writers.write_ros2_bag(tmp_path / "bag", writers.joint_recording(n=20))
        text = (bag / "metadata.yaml").read_text()
        count = yaml.safe_load(text)["rosbag2_bagfile_information"]["message_count"]
        text = text.replace(f"message_count: {count}", f"message_count: {WIDE}", 1)
        (bag / "metadata.yaml").write_text(text)
        cfg.write_text("data:\n  state: {topic: /joint_states, field: position}\n")
        for command in (["inspect", bag], ["convert", bag, "-o", tmp_path / "o.h5", "-c", cfg]):
            code, _, err = run_main(capsys, *command)
            assert code == 2 and re.search(r"metadata.yaml:\d+: rosbag2_bagfile_information\..*message_count "
                                           "is an integer of 5000 digits", one_line_error(err)), err
    elif where == "job_record":  # a tampered job.json: the job runs again instead of failing
        data = copy(fixtures["data"], tmp_path / "toy.h5")
        cfg.write_text("stages: [learn-a]\noutput: {plots: false}\ndata: {test: {fraction: 0}}\n")
        args = ["batch", "--files", data, "-c", cfg, "-o", tmp_path / "b", "-j", "1", "--json", "-q"]
        assert run_main(capsys, *args)[0] == 0
        record = next((tmp_path / "b" / "jobs").iterdir()) / "job.json"
        record.write_text(f'{{"key": {WIDE}}}')
        code, out, err = run_main(capsys, *args)
        assert code == 0 and json.loads(out)["ok"] == 1, err
    else:
        model = copy(fixtures["model"], tmp_path / "m.h5")
        attr = where.split("_")[1]
        with h5py.File(model, "a") as f:
            value = json.loads(f.attrs[attr])
            first = next(iter(value))
            f.attrs[attr] = json.dumps({**value, first: 0}, indent=1).replace(": 0", f": {WIDE}", 1)
        for command in (["predict", model, fixtures["data"], "-o", tmp_path / "p.csv"], ["inspect", model]):
            code, _, err = run_main(capsys, *command)
            assert code == 2 and f"attribute '{attr}' line 2: {first} is an integer of 5000 digits" \
                in one_line_error(err)


@pytest.mark.parametrize("text,match", [
    ("seed: 1\nseed: 2\n", "c.yaml:2: duplicate key 'seed' at the top level (lines 1 and 2)"),
    ("data:\n  test: {fraction: 0.2}\n  state: {columns: [x]}\n  test: {seed: 3}\n",
     "c.yaml:4: duplicate key 'test' in data (lines 2 and 4)"),
    ("stages:\n  - learn-a: {method: nhat, method: alpha}\n",
     "c.yaml:2: duplicate key 'method' in stages[0].learn-a (lines 2 and 2)"),
])
def test_duplicate_yaml_keys_are_refused_naming_both_lines(capsys, fixtures, tmp_path, text, match):
    """PyYAML keeps the last of two equal keys silently; a config saying two things is refused."""
    (tmp_path / "c.yaml").write_text(text)
    code, _, err = run_main(capsys, "learn-a", fixtures["data"], "-c", tmp_path / "c.yaml", "-o",
                            tmp_path / "o")
    assert code == 2 and match in one_line_error(err)


def test_a_key_bomb_is_refused_before_it_is_built(capsys, fixtures, tmp_path):
    """A 3.4-MB config of 200,000 keys: refused while only the parser's events are walked —
    no node built (it was refused after composing 400,003 nodes: 22–50 s and ~370 MB)."""
    import tracemalloc

    from ccl_cli import config as C

    bomb = tmp_path / "bomb.yaml"
    bomb.write_text("data:\n" + "".join(f"  k{i:06d}: {i}\n" for i in range(200_000)))
    assert bomb.stat().st_size > 3.4e6
    tracemalloc.start()
    t0 = cpu_seconds()
    with pytest.raises(C.ConfigError, match=r"bomb.yaml:50000: config has more than 100000 values"):
        C.load(bomb)
    seconds, peak = cpu_seconds() - t0, tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    assert peak < 60e6 and seconds < 3, (peak, seconds)  # the text and its decoding, no nodes
    code, _, err = run_main(capsys, "learn-a", fixtures["data"], "-c", bomb)
    assert code == 2 and "key or alias bomb" in one_line_error(err)


# -- never lose data ---------------------------------------------------------------------------
def test_force_never_replaces_a_folder_ccl_did_not_write(capsys, fixtures, tmp_path):
    mine = tmp_path / "thesis"
    mine.mkdir()
    (mine / "chapter1.tex").write_text("years of work")
    (mine / "metrics.json").write_text("{}")  # looks a bit like an output, still not ours
    code, _, err = run_main(capsys, "learn-v", fixtures["data"], "-o", mine, "--force", "-q")
    assert code == 2 and "was not written by ccl" in one_line_error(err)
    assert "remove it yourself" in err and "holds a run.json" not in err
    assert (mine / "chapter1.tex").read_text() == "years of work"
    assert sorted(p.name for p in tmp_path.iterdir()) == ["thesis"]
    afile = tmp_path / "notes.txt"
    afile.write_text("mine")
    code, _, err = run_main(capsys, "learn-v", fixtures["data"], "-o", afile, "--force", "-q")
    assert code == 2 and afile.read_text() == "mine"
    # a folder ccl wrote is replaced, and carries the marker
    out = tmp_path / "out"
    for _ in range(2):
        code, _, err = run_main(capsys, "learn-v", fixtures["data"], "-o", out, "--force", "-q")
        assert code == 0, err
    assert (out / ".ccl-output").is_file()


@pytest.mark.parametrize("marker", [None, "empty", "other", "symlink", "fifo", "folder"])
def test_force_never_replaces_a_folder_holding_a_look_alike_run_json(capsys, fixtures, tmp_path, marker):
    """A user's folder holding a run.json with command and versions (what ccl's outputs held
    before the marker; any tool may write one), with or without a .ccl-output that is not
    ccl's: --force refuses it in one line naming the hint, every file intact (it was deleted)."""
    mine = tmp_path / "results"
    mine.mkdir()
    files = {"run.json": json.dumps({"command": "my-tool", "versions": {"my-tool": "1.0"}}),
             "data.csv": "1,2,3\n", "notes.md": "two years of notes\n"}
    for name, text in files.items():
        (mine / name).write_text(text)
    outside = tmp_path / "elsewhere.json"
    outside.write_text(json.dumps({"written_by": "ccl"}))
    if marker == "empty":
        (mine / ".ccl-output").write_text("")
    elif marker == "other":
        (mine / ".ccl-output").write_text(json.dumps({"written_by": "another tool"}))
    elif marker == "symlink":  # ccl's content, but not a file of the folder
        (mine / ".ccl-output").symlink_to(outside)
    elif marker == "fifo":
        os.mkfifo(mine / ".ccl-output")
    elif marker == "folder":
        (mine / ".ccl-output").mkdir()
    code, _, err = run_main(capsys, "learn-a", fixtures["data"], "-o", mine, "--force", "-q")
    line = one_line_error(err)
    assert code == 2 and "--force replaces only folders ccl marked" in line
    assert "holds a run.json but no .ccl-output marker of ccl's" in line and "remove it yourself" in line
    assert {p.name: p.read_text() for p in mine.iterdir() if p.is_file() and not p.is_symlink()
            and p.name != ".ccl-output"} == files
    assert sorted(p.name for p in tmp_path.iterdir()) == ["elsewhere.json", "results"]


def test_force_as_an_unprivileged_user(fixtures):
    """As the user nobody (where permissions matter): an output nobody wrote is replaced with
    --force; a look-alike folder, and one whose marker nobody cannot read, are refused with
    every file intact."""
    import shutil
    import subprocess

    from tests_paths import CCL, as_nobody, shared_folder

    prefix = as_nobody()
    root = shared_folder()
    try:
        data = copy(fixtures["data"], root / "toy.h5")
        data.chmod(0o644)

        def ccl(*args):
            proc = subprocess.run([*prefix, CCL, *map(str, args), "-q"], capture_output=True, text=True,
                                  timeout=300, cwd=root)
            return proc.returncode, proc.stderr

        code, err = ccl("learn-a", data, "-o", root / "out")
        assert code == 0, err
        code, err = ccl("learn-a", data, "-o", root / "out", "--force")
        assert code == 0, err
        mine = root / "mine"
        mine.mkdir()
        (mine / "run.json").write_text(json.dumps({"command": "x", "versions": {}}))
        (mine / "keep.txt").write_text("mine")
        (mine / ".ccl-output").write_text(json.dumps({"written_by": "ccl"}))
        (mine / ".ccl-output").chmod(0o000)  # a marker this user cannot read is no marker
        mine.chmod(0o777)
        code, err = ccl("learn-a", data, "-o", mine, "--force")
        assert code == 2 and "--force replaces only folders ccl marked" in one_line_error(err)
        assert (mine / "keep.txt").read_text() == "mine" and (mine / "run.json").exists()
    finally:
        shutil.rmtree(root, ignore_errors=True)


def test_stale_temporaries_of_a_killed_run_are_removed(capsys, fixtures, tmp_path):
    import subprocess
    import sys

    dead = subprocess.Popen([sys.executable, "-c", "pass"])
    dead.wait()
    out = tmp_path / "out"
    stale = tmp_path / f".out.{dead.pid}.k1ll3d.tmp"
    stale.mkdir()
    (stale / "model.h5").write_bytes(b"half")
    stale_old = tmp_path / f".out.old-{dead.pid}"
    stale_old.mkdir()
    live = tmp_path / f".out.{os.getpid()}.busy.tmp"  # a run still going: left alone
    live.mkdir()
    code, _, err = run_main(capsys, "learn-v", fixtures["data"], "-o", out, "-q")
    assert code == 0, err
    assert not stale.exists() and not stale_old.exists() and live.exists()


@pytest.mark.parametrize("umask,dmode,fmode", [(0o022, 0o755, 0o644), (0o077, 0o700, 0o600)])
def test_outputs_follow_the_umask(capsys, fixtures, tmp_path, umask, dmode, fmode):
    old = os.umask(umask)
    try:
        code, _, err = run_main(capsys, "learn-v", fixtures["data"], "-o", tmp_path / "o", "-q")
        code2, _, _ = run_main(capsys, "predict", tmp_path / "o" / "model.h5", fixtures["data"],
                               "-o", tmp_path / "p.h5")
    finally:
        os.umask(old)
    assert code == 0 and code2 == 0, err
    assert (tmp_path / "o").stat().st_mode & 0o777 == dmode
    for path in [*(tmp_path / "o").rglob("*"), tmp_path / "p.h5"]:
        assert path.stat().st_mode & 0o777 == (dmode if path.is_dir() else fmode), path


def test_disk_full_is_one_line_and_leaves_nothing(fixtures, tmp_path):
    """RLIMIT_FSIZE makes every write past 64 kB fail (EFBIG), as a full disk would."""
    import resource
    import subprocess

    from tests_paths import CCL

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (64_000, 64_000))

    proc = subprocess.run([CCL, "learn-v", str(fixtures["data"]), "-o", str(tmp_path / "o"), "-q"],
                          capture_output=True, text=True, preexec_fn=limit, timeout=300)
    assert proc.returncode == 2, proc.stderr
    line = one_line_error(proc.stderr)
    assert "cannot write the output" in line and "nothing was written" in line
    assert list(tmp_path.iterdir()) == []


def test_read_only_output_folder_is_one_line(fixtures, tmp_path):
    """Run as a user that permissions bind: as root (how CI runs), ccl runs without the
    capabilities that let root write anywhere (setpriv drops CAP_DAC_OVERRIDE)."""
    import subprocess

    from tests_paths import CCL

    prefix = unprivileged()
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        proc = subprocess.run([*prefix, CCL, "learn-v", str(fixtures["data"]), "-o", str(ro / "o"), "-q"],
                              capture_output=True, text=True, timeout=300)
    finally:
        ro.chmod(0o755)
    assert proc.returncode == 2 and "cannot write the output" in one_line_error(proc.stderr), proc.stderr
    assert list(ro.iterdir()) == []


def unprivileged() -> list[str]:
    """A prefix that runs a command as a user that permissions bind: as root (how CI runs),
    without the capabilities that let root write anywhere (setpriv drops CAP_DAC_OVERRIDE)."""
    import shutil

    if os.geteuid() != 0:
        return []
    setpriv = shutil.which("setpriv")
    assert setpriv, "setpriv (util-linux) is needed to run this test as root"
    return [setpriv, "--bounding-set=-dac_override,-dac_read_search", "--inh-caps=-all", "--"]


def test_batch_under_a_read_only_parent_is_one_line(fixtures, tmp_path):
    import subprocess

    from tests_paths import CCL

    cfg = tmp_path / "pipeline.yaml"
    cfg.write_text("learn-a: {method: nhat}\nstages: [learn-a]\noutput: {plots: false}\n")
    ro = tmp_path / "ro"
    ro.mkdir()
    ro.chmod(0o555)
    try:
        proc = subprocess.run([*unprivileged(), CCL, "batch", "--files", str(fixtures["data"]), "-c",
                               str(cfg), "-o", str(ro / "out"), "-q", "-j", "1"], capture_output=True,
                              text=True, timeout=300)
    finally:
        ro.chmod(0o755)
    line = one_line_error(proc.stderr)
    assert proc.returncode == 2 and "cannot write the output (Permission denied)" in line, proc.stderr
    assert list(ro.iterdir()) == []


@pytest.mark.parametrize("command", ["learn-a", "learn-v", "batch"])
def test_file_size_limit_is_one_line_and_leaves_nothing(fixtures, tmp_path, command):
    """``ulimit -f 8`` (4 for the batch): every write past it fails (SIGXFSZ ignored: EFBIG),
    in ccl and in its batch workers; exit 2, one line, no temporary left."""
    import resource
    import subprocess

    from tests_paths import CCL

    cfg = tmp_path / "pipeline.yaml"
    cfg.write_text("learn-a: {method: nhat}\nstages: [learn-a]\noutput: {plots: false}\n")
    work = tmp_path / "work"
    work.mkdir()
    argv = {"learn-a": ["learn-a", str(fixtures["data"]), "-o", "out"],
            "learn-v": ["learn-v", str(fixtures["data"]), "-o", "out", "--n-centres", "4"],
            "batch": ["batch", "--files", str(fixtures["data"]), "-c", str(cfg), "-o", "out", "-j", "1"],
            }[command]

    # a batch with plots: false writes no summary.png: at 4 kB its worker's model.h5 is the write that fails
    size = 4096 if command == "batch" else 8192

    def limit():
        resource.setrlimit(resource.RLIMIT_FSIZE, (size, size))

    proc = subprocess.run([CCL, *argv, "-q"], capture_output=True, text=True, preexec_fn=limit, timeout=300,
                          cwd=work)
    assert proc.returncode == 2, proc.stderr
    assert "cannot write the output (File too large); nothing was written" in one_line_error(proc.stderr)
    assert list(work.iterdir()) == []


# -- faults ------------------------------------------------------------------------------------
def test_ctrl_c_wrapped_by_python_is_still_130_and_one_line(fixtures, tmp_path, monkeypatch, capsys):
    """Python 3.11 wraps a KeyboardInterrupt that lands while an imported module creates a class
    in RuntimeError("Error calling __set_name__ ..."): still an interruption, not an internal error."""
    from ccl_cli import cli

    def interrupted(*args, **kwargs):
        try:
            raise KeyboardInterrupt
        except KeyboardInterrupt as exc:
            raise RuntimeError("Error calling __set_name__ on 'Field' instance 'values'") from exc

    monkeypatch.setattr(cli, "_learn", interrupted)
    assert cli.main(["learn-v", str(fixtures["data"]), "-o", str(tmp_path / "o"), "-q"]) == 130
    assert capsys.readouterr().err.strip().splitlines() == ["ccl: interrupted; no partial outputs were left"]


@pytest.mark.parametrize("delay", [0.0, 0.05, 0.15, 0.4])
def test_ctrl_c_at_any_moment_is_130_and_one_line(fixtures, tmp_path, delay):
    """SIGINT while ccl imports its modules (delay 0: the first ones), reads, learns or
    writes: exit 130, one line, nothing left."""
    import signal
    import subprocess

    from tests_paths import CCL, wait_for_ccl_code

    proc = subprocess.Popen([CCL, "learn-v", str(fixtures["data"]), "-o", str(tmp_path / "o"), "-q"],
                            stderr=subprocess.PIPE, text=True)
    wait_for_ccl_code(proc)
    time.sleep(delay)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=120)
    if proc.returncode == 0:  # finished first: complete
        assert (tmp_path / "o" / "model.h5").exists()
        return
    assert proc.returncode == 130, err
    said = [line for line in err.strip().splitlines() if not line.startswith("ccl: warning: ")]
    assert said == ["ccl: interrupted; no partial outputs were left"]  # warnings of stages already done aside
    assert list(tmp_path.iterdir()) == []
