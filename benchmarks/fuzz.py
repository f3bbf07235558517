"""Mutation fuzzing of every input ccl reads. Prints one JSON object with outcome counts.

Fixtures are written at run time by the real writers (h5py through ccl's own
write_demonstrations and save_model, rosbags, mcap, mcap-ros1/ros2, csv; see
tests/writers.py): CSV, canonical HDF5, model files of every method, MCAP (ROS 2 CDR,
ROS 1, JSON), ROS 1 bags, ROS 2 bags (sqlite3 and mcap storage, and their
metadata.yaml), pipeline configs (YAML) and batch manifests. Each case mutates one of
them — byte flips, truncation, zeroed blocks, inserted/deleted bytes, or a structural
edit (a CSV cell, a YAML/JSON value, an HDF5 attribute or dataset replaced by one of
another type, shape or value, links and external storage) — and runs the command that
reads it (``ccl convert`` / ``learn-a`` / ``inspect`` for recordings, ``predict`` /
``export`` / ``inspect`` for models, ``run`` for configs, the manifest planner for
manifests) in a forked child with a wall-clock limit.

Mixes (``--mix``): ``classic`` — the mutations above; ``hostile`` and ``even`` — 70 % / 35 %
of the cases instead get one of issue 20: datasets declaring gigabytes they do not hold
(HDF5, models, MATLAB v7.3), sparse and huge-sparse matrices in MATLAB v5 files, CSV lines
over the line cap (run with ``CCL_MAX_BYTES=1M``), damaged attribute tables, inputs
replaced by FIFOs, sockets, folders or /dev/zero (also the storage files a ROS 2 bag's
metadata names), storage files and manifest paths outside their folder, and JSON MCAP
messages missing a key or holding one of another type. ``round4`` — 70 % get one of issue
28 instead: ROS 1 chunk and index positions outside the file, 5,000-digit integers (YAML,
JSON attributes, CSV cells, JSON messages), input names that are not UTF-8, CSVs with
thousands of columns no config reads, YAML key bombs and duplicate keys; ``all`` — 30 % of
each kind. Peak RSS of each case's process is recorded (``peak_rss_mb``, ``over_500MB``)
beside its time (``over_20s``).

Outcomes per format: ``ok`` (exit 0), ``error`` (exit 2, one ``ccl: error:`` line),
``exit1`` (a learning failure, one line), ``internal`` (anything but our error classes:
an internal error, a traceback, a multi-line message), ``crash`` (killed by a signal)
and ``timeout`` (over ``--timeout`` seconds). Internal errors are grouped by exception
type and the innermost ccl_cli frame.

Run:  python benchmarks/fuzz.py --cases 20000 [--seed 0] [--mix hostile] [--timeout 20] [--subprocess 200]
"""

from __future__ import annotations

import argparse
import collections
import copy
import inspect
import json
import os
import random
import shutil
import signal
import struct
import subprocess
import sys
import tempfile
import time
import traceback
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

OUTCOMES = ("ok", "error", "exit1", "internal", "crash", "timeout")
VALUES: list[Any] = [0, -1, 1, 2, 3, 2.5, -0.5, 1e300, -1e300, 10**30, "", "x", "nan", "inf", "1.0", None,
                     True, False, [], {}, [1, 2], [[1, 2], [3]], {"a": 1}, [0, 1e300], "é" * 3, [None]]


# -- fixtures ------------------------------------------------------------------------------------
def _yaml(data: Any) -> str:
    import yaml

    return yaml.safe_dump(data, sort_keys=False)


def build_fixtures(root: Path) -> list[dict[str, Any]]:
    """Every base input with the command that reads it. Returns a list of
    {format, path (the file mutated), argv (with {path}/{out} placeholders) or plan}."""
    import writers

    from ccl_cli import simulate as sim
    from ccl_cli.cli import main
    from ccl_cli.io import write_demonstrations

    root.mkdir(parents=True, exist_ok=True)
    rec = writers.joint_recording(n=60, gap_after=30)
    bases: list[dict[str, Any]] = []
    joints = {"topic": "/joint_states", "field": "position", "joints": writers.JOINTS[:3]}
    bag_cfg = root / "bag.yaml"
    bag_cfg.write_text(_yaml({"data": {"state": joints, "action": {"derive": "state", "window": 5},
                                       "demos": {"split_on_gap": 0.5}},
                              "learn-a": {"method": "nhat"}, "stages": ["learn-a"],
                              "output": {"plots": False}}))
    for name in ("ros1", "ros2-sqlite3", "ros2-mcap", "mcap-ros2", "mcap-ros1", "mcap-json"):
        d = root / name
        d.mkdir()
        out = writers.WRITERS[name](d, rec)
        fmt = "ros2" if name.startswith("ros2") else "ros1" if name == "ros1" else "mcap"
        files = [out] if out.is_file() else sorted(p for p in out.iterdir() if p.suffix in (".db3", ".mcap"))
        for f in files:
            bases.append({"format": fmt, "name": name, "path": f, "input": out, "config": bag_cfg})
        if out.is_dir():
            bases.append({"format": "ros2-metadata", "name": name, "path": out / "metadata.yaml",
                          "input": out, "config": bag_cfg, "yaml": True})
    csv_path = writers.write_csv(root / "rec.csv", rec)
    csv_cfg = root / "csv.yaml"
    csv_cfg.write_text(_yaml({"data": {"state": {"columns": ["x", "y", "z"]},
                                       "action": {"derive": "state", "window": 5, "order": 2},
                                       "time": {"column": "%time", "unit": "ns"},
                                       "demos": {"split_on_gap": 0.5}},
                              "learn-a": {"method": "nhat"}, "stages": ["learn-a"],
                              "output": {"plots": False}}))
    bases.append({"format": "csv", "name": "csv", "path": csv_path, "input": csv_path, "config": csv_cfg})
    bases += mat_fixtures(root)
    # canonical HDF5 and models
    toy = root / "toy2d.h5"
    write_demonstrations(toy, sim.toy2d(n_demos=4, n_steps=40, seed=0), masks={"train": [0, 1, 2],
                                                                              "test": [3]})
    parabola = root / "parabola.h5"
    write_demonstrations(parabola, sim.toy2d(constraint="parabola", n_demos=4, n_steps=40, seed=1))
    arm = root / "two_link.h5"
    write_demonstrations(arm, sim.two_link(n_demos=3, n_steps=30, seed=2))
    bases.append({"format": "hdf5", "name": "hdf5", "path": toy, "input": toy, "config": None})
    models = {
        "nhat": (toy, ["learn-a", "--method", "nhat"]),
        "per_demo": (toy, ["learn-a", "--method", "nhat", "--per-demo"]),
        "auto": (parabola, ["learn-a"]),
        "manifold": (toy, ["learn-a", "--method", "manifold"]),
        "linear": (parabola, ["learn-a", "--method", "linear", "--regressors", "polynomial",
                              "--degree", "2"]),
        "alpha": (parabola, ["learn-a", "--method", "alpha", "--n-centres", "4"]),
        "lambda": (arm, ["learn-a", "--method", "lambda", "--features", "arm2", "--n-centres", "4"]),
        "ncl": (toy, ["learn-v", "--n-centres", "4"]),
        "policy": (toy, ["learn-pi", "--n-centres", "4"]),
        "lwpi": (toy, ["learn-pi", "--method", "lwpi", "--n-centres", "4"]),
    }
    for name, (data, argv) in models.items():
        out = root / f"model_{name}"
        null = os.open(os.devnull, os.O_WRONLY)
        saved = os.dup(2)
        os.dup2(null, 2)
        try:
            code = main([*argv, str(data), "-o", str(out), "-q", "--test-fraction", "0"])
        finally:
            os.dup2(saved, 2)
            os.close(null)
            os.close(saved)
        if code == 0:
            bases.append({"format": "model", "name": f"model-{name}", "path": out / "model.h5",
                          "input": out / "model.h5", "data": data})
    # a pipeline config and a batch manifest
    cfg = root / "pipeline.yaml"
    cfg.write_text(_yaml({"seed": 0, "data": {"files": [str(toy)], "test": {"fraction": 0.3, "seed": 0}},
                          "learn-a": {"method": "nhat", "selection": "eigengap"},
                          "learn-pi": {"method": "pi", "n_centres": 4},
                          "stages": ["learn-a", {"learn-pi": {"on": "u"}}], "output": {"plots": False}}))
    bases.append({"format": "config", "name": "config", "path": cfg, "input": cfg, "yaml": True})
    csv_pipeline = root / "csv_pipeline.yaml"
    csv_pipeline.write_text(csv_cfg.read_text().replace("data:", f"data:\n  files: [{csv_path}]", 1))
    bases.append({"format": "config", "name": "config-csv", "path": csv_pipeline, "input": csv_pipeline,
                  "yaml": True})
    manifest = root / "batch.yaml"
    manifest.write_text(_yaml({"out": "runs", "jobs": [
        {"files": [str(toy), str(parabola)], "config": str(cfg),
         "overrides": {"learn-a": {"n_constraints": 1}}},
        {"files": str(arm), "config": str(cfg), "group": True}],
        "overrides": {str(toy): {"seed": 3}}}))
    bases.append({"format": "manifest", "name": "manifest", "path": manifest, "input": manifest,
                  "yaml": True})
    return bases


def mat_fixtures(root: Path) -> list[dict[str, Any]]:
    """MATLAB files of a 7-joint arm: v5 (scipy.io.savemat; matrices, one sample per column)
    and v7.3 (h5py in MATLAB's layout; one cell per demonstration), with their configs."""
    import scipy.io
    import writers

    from ccl_cli import simulate as sim

    arm = sim.arm7(seed=0, n_demos=3, n_steps=20)
    v5 = root / "arm.mat"
    scipy.io.savemat(v5, {"X": arm.X.T, "U": arm.U.T, "demo": arm.demo[None, :] + 1.0})
    stage = {"learn-a": {"method": "nhat"}, "stages": ["learn-a"], "output": {"plots": False}}
    v5_cfg = root / "mat5.yaml"
    v5_cfg.write_text(_yaml({"data": {"format": "mat", "state": {"variable": "X", "samples": "columns"},
                                      "action": {"variable": "U", "samples": "columns"},
                                      "time": {"rate": 50}, "demos": {"variable": "demo"}}, **stage}))
    cells = {k: [v[arm.demo == d].T for d in arm.demo_ids] for k, v in (("X", arm.X), ("U", arm.U))}
    v73 = writers.write_mat73(root / "arm73.mat", cells)
    v73_cfg = root / "mat73.yaml"
    v73_cfg.write_text(_yaml({"data": {"state": {"variable": "X", "samples": "columns"},
                                       "action": {"variable": "U", "samples": "columns"},
                                       "time": {"rate": 50}}, **stage}))
    return [{"format": "mat5", "name": "mat5", "path": v5, "input": v5, "config": v5_cfg},
            {"format": "mat73", "name": "mat73", "path": v73, "input": v73, "config": v73_cfg}]


# -- mutations -------------------------------------------------------------------------------------
def byte_mutation(raw: bytes, rng: random.Random) -> tuple[str, bytes]:
    b = bytearray(raw)
    op = rng.choice(["flip", "flip", "zero", "truncate", "insert", "delete"])
    if not b:
        return "empty", bytes(b)
    if op == "flip":
        for _ in range(rng.randint(1, 8)):
            k = rng.randrange(len(b))
            b[k] ^= 1 << rng.randrange(8)
    elif op == "zero":
        k = rng.randrange(len(b))
        n = rng.choice([1, 4, 16, 64, 512])
        b[k:k + n] = bytes(len(b[k:k + n]))
    elif op == "truncate":
        b = b[:rng.randrange(len(b))]
    elif op == "insert":
        k = rng.randrange(len(b))
        b[k:k] = bytes(rng.randrange(256) for _ in range(rng.randint(1, 16)))
    else:
        k = rng.randrange(len(b))
        del b[k:k + rng.randint(1, 16)]
    return op, bytes(b)


def _paths(obj: Any, prefix: tuple = ()) -> list[tuple]:
    out = [prefix]
    if isinstance(obj, dict):
        for k, v in obj.items():
            out += _paths(v, (*prefix, k))
    elif isinstance(obj, list):
        for i, v in enumerate(obj):
            out += _paths(v, (*prefix, i))
    return out


def mutate_tree(data: Any, rng: random.Random) -> Any:
    """A YAML/JSON value with one node replaced, deleted or given an unknown sibling."""
    data = copy.deepcopy(data)
    paths = [p for p in _paths(data) if p]
    if not paths:
        return rng.choice(VALUES)
    path = rng.choice(paths)
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    op = rng.random()
    if op < 0.7:
        parent[path[-1]] = copy.deepcopy(rng.choice(VALUES))
    elif op < 0.85 and isinstance(parent, dict):
        del parent[path[-1]]
    elif isinstance(parent, dict):
        parent[rng.choice(["unknown", "x", 1, "files"])] = copy.deepcopy(rng.choice(VALUES))
    else:
        parent.append(copy.deepcopy(rng.choice(VALUES)))
    return data


def yaml_mutation(raw: bytes, rng: random.Random) -> tuple[str, bytes]:
    import yaml

    r = rng.random()
    if r < 0.05:
        return "alias-bomb", ("a: &a [x, x, x, x, x, x, x, x]\n" + "".join(
            f"{c}: &{c} [{', '.join(['*' + p] * 8)}]\n" for p, c in zip("abcdefgh", "bcdefghi", strict=True))
            ).encode()
    if r < 0.08:
        n = rng.choice([100, 5000, 30000])
        return "deep", ("data: " + "[" * n + "]" * n + "\n").encode()
    if r < 0.11:
        k = rng.randrange(max(1, len(raw)))
        return "non-utf8", raw[:k] + bytes([rng.choice([0xC3, 0xE9, 0xFF, 0x80])]) + raw[k:]
    data = yaml.safe_load(raw)
    return "tree", yaml.safe_dump(mutate_tree(data, rng), sort_keys=False, allow_unicode=True).encode()


def csv_mutation(raw: bytes, rng: random.Random) -> tuple[str, bytes]:
    lines = raw.decode().splitlines()
    i = rng.randrange(len(lines))
    cells = lines[i].split(",")
    j = rng.randrange(len(cells))
    special = rng.choice(["1e300", "-1e300", "inf", "-inf", "nan", "", "x", "1e999", "0x10", "１２",
                          "9" * 400, "x" * 200_000, "1.5.5", "+", "-", '"', "\x00", "1_000", "١"])
    op = rng.random()
    if op < 0.6:
        cells[j] = special
        lines[i] = ",".join(cells)
    elif op < 0.7:
        del lines[i]
    elif op < 0.8:
        lines.insert(i, lines[i])
    elif op < 0.9:
        lines[i] = ",".join(c for k, c in enumerate(cells) if k != j)
    else:
        lines[i], lines[-1] = lines[-1], lines[i]
    return "cell", ("\n".join(lines) + "\n").encode()


def hdf5_mutation(path: Path, rng: random.Random) -> str:
    """Edit a copy of an HDF5 file in place with h5py (structural)."""
    import h5py
    import numpy as np

    with h5py.File(path, "a") as f:
        objects = [f]
        f.visititems(lambda name, obj: objects.append(obj))
        obj = rng.choice(objects)
        op = rng.random()
        if op < 0.35 and len(obj.attrs):
            key = rng.choice(list(obj.attrs))
            value = obj.attrs[key]
            text = value.decode() if isinstance(value, bytes) else value
            if isinstance(text, str) and text[:1] in "[{" and rng.random() < 0.7:
                try:
                    obj.attrs[key] = json.dumps(mutate_tree(json.loads(text), rng))
                    return f"attr-json:{key}"
                except (json.JSONDecodeError, TypeError, ValueError):
                    pass
            new = rng.choice(["1.0", "x", np.array([1, 2]), 1.5, -3, 10**18, np.nan, b"\xff\xfe",
                              np.array(["a", "b"], dtype=object), np.zeros((2, 2)), True, ""])
            if isinstance(new, np.ndarray) and new.dtype == object:
                obj.attrs.create(key, new, dtype=h5py.string_dtype())
            else:
                obj.attrs[key] = new
            return f"attr:{key}"
        datasets = [o for o in objects if isinstance(o, h5py.Dataset)]
        if op < 0.75 and datasets:
            ds = rng.choice(datasets)
            name, shape = ds.name, ds.shape
            data = ds[()]
            del f[name]
            choice = rng.choice(["nan", "inf", "huge", "string", "3d", "scalar", "empty", "transpose",
                                 "int", "short", "external", "softlink"])
            if choice in ("nan", "inf", "huge") and getattr(data, "dtype", None) is not None \
                    and data.dtype.kind == "f" and data.size:
                data = np.array(data)
                data.flat[rng.randrange(data.size)] = {"nan": np.nan, "inf": np.inf, "huge": 1e308}[choice]
                f[name] = data
            elif choice == "string":
                f.create_dataset(name, data=np.array(["a", "b"], dtype=object), dtype=h5py.string_dtype())
            elif choice == "3d":
                f[name] = np.zeros((*shape[:2], 2)) if len(shape) else np.zeros((2, 2, 2))
            elif choice == "scalar":
                f[name] = 1.0
            elif choice == "empty":
                f[name] = np.zeros((0,) + tuple(shape[1:]))
            elif choice == "transpose" and getattr(data, "ndim", 0) == 2:
                f[name] = np.asarray(data).T
            elif choice == "int":
                f[name] = np.arange(max(1, int(np.prod(shape))) if shape else 1).reshape(shape or ())
            elif choice == "short" and shape:
                f[name] = np.asarray(data)[: max(0, shape[0] - 1)]
            elif choice == "external":
                f.create_dataset(name, shape=shape or (1,), dtype="f8",
                                 external=[("/etc/hostname", 0, 8 * max(1, int(np.prod(shape or (1,)))))])
            else:
                f[name] = h5py.SoftLink("/nowhere")
            return f"dataset:{choice}"
        if op < 0.9 and obj.name != "/":
            del f[obj.name]
            return "delete"
        f["extra"] = h5py.ExternalLink("/etc/hostname", "/x")
        return "external-link"


# -- hostile mutations (issue 20): bombs, special files, paths that leave their folder -------------
#: a manifest case with this variable set is planned without --allow-outside (the fixture
#: manifest names files in another folder, as manifests with absolute paths do)
BOUNDED = "CCL_FUZZ_BOUNDED"
#: cap of the cases that test it (CCL_MAX_BYTES): small, so that a bomb costs little to write
SMALL_CAP = "1M"
HUGE = [(400_000_000, 3), (1_000_000_000,), (3, 400_000_000), (100_000, 100_000)]


def bomb_dataset(path: Path, rng: random.Random) -> str:
    """An HDF5 dataset (x, u, a model's weights, a MATLAB variable) replaced by a chunked one
    that declares a huge shape and holds no data: a file of a few KB claiming GBs."""
    import h5py

    with h5py.File(path, "a") as f:
        found: list[str] = []
        f.visititems(lambda name, obj: found.append(name) if isinstance(obj, h5py.Dataset) else None)
        found = [n for n in found if not n.startswith("#refs#") or rng.random() < 0.5]
        if not found:
            return "bomb:none"
        name = rng.choice(found)
        attrs = dict(f[name].attrs)
        del f[name]
        shape = rng.choice(HUGE)
        ds = f.create_dataset(name, shape=shape, dtype=rng.choice(["f8", "f4", "u1"]),
                              chunks=tuple(min(d, 1024) for d in shape),
                              compression=rng.choice([None, "gzip"]))
        for key, value in attrs.items():
            ds.attrs[key] = value
    return f"bomb:{'x'.join(map(str, shape))}"


#: attribute names whose neighbourhood is damaged (the attribute messages and heaps)
ATTR_NAMES = [b"format", b"schema_version", b"format_version", b"kind", b"method", b"params", b"fitted",
              b"MATLAB_class", b"state_names", b"index", b"n_samples", b"provenance", b"sigma2"]


def damage_attributes(raw: bytes, rng: random.Random) -> tuple[str, bytes]:
    """Byte damage next to an attribute's name: its message, datatype, dataspace or heap."""
    hits = [(n, m) for n in ATTR_NAMES for m in _find_all(raw, n)]
    if not hits:
        return byte_mutation(raw, rng)
    name, at = rng.choice(hits)
    b = bytearray(raw)
    for _ in range(rng.randint(1, 6)):
        k = min(len(b) - 1, max(0, at + rng.randint(-48, len(name) + 48)))
        b[k] = rng.randrange(256) if rng.random() < 0.5 else b[k] ^ (1 << rng.randrange(8))
    return f"attr-table:{name.decode()}", bytes(b)


def _find_all(raw: bytes, needle: bytes) -> list[int]:
    out, k = [], raw.find(needle)
    while k >= 0 and len(out) < 50:
        out.append(k)
        k = raw.find(needle, k + 1)
    return out


def special_file(target: Path, rng: random.Random) -> str:
    """The input replaced by what is not a regular file: a FIFO (a read would block forever),
    /dev/zero (a read never ends), a socket, a folder, or a symlink to one of them."""
    import socket

    if target.is_dir():
        shutil.rmtree(target)
    else:
        target.unlink()
    kind = rng.choice(["fifo", "fifo", "dev-zero", "socket", "folder", "link-fifo"])
    if kind == "fifo":
        os.mkfifo(target)
    elif kind == "dev-zero":
        target.symlink_to("/dev/zero")
    elif kind == "socket":
        sock = socket.socket(socket.AF_UNIX)
        try:
            sock.bind(str(target))
        except OSError:  # a path too long for a socket: a FIFO instead
            os.mkfifo(target)
            kind = "fifo"
        finally:
            sock.close()
    elif kind == "folder":
        target.mkdir()
    else:
        fifo = target.with_name(target.name + ".fifo")
        os.mkfifo(fifo)
        target.symlink_to(fifo)
    return f"special:{kind}"


def outside_storage(bag: Path, target: Path, rng: random.Random) -> str:
    """A ROS 2 bag whose storage file lives outside its folder: symlinked back in, or named
    through ../ in metadata.yaml."""
    import yaml

    outside = bag.parent / f"elsewhere_{target.name}"
    shutil.move(str(target), outside)
    if rng.random() < 0.5:
        target.symlink_to(outside)
        return "outside:symlink"
    meta_path = bag / "metadata.yaml"
    meta = yaml.safe_load(meta_path.read_text())
    info = meta["rosbag2_bagfile_information"]
    info["relative_file_paths"] = [f"../{outside.name}" if p == target.name else p
                                   for p in info.get("relative_file_paths", [])]
    for entry in info.get("files", []) or []:
        if entry.get("path") == target.name:
            entry["path"] = f"../{outside.name}"
    meta_path.write_text(yaml.safe_dump(meta, sort_keys=False))
    return "outside:dotdot"


def json_messages(target: Path, rng: random.Random) -> str:
    """The JSON MCAP rewritten with messages missing a key or holding one of another type."""
    import writers

    rec = writers.joint_recording(n=60, gap_after=30)
    msgs = [writers.msg_dict(rec, i) for i in range(len(rec.t_ns))]
    key = rng.choice(["name", "position", "velocity", "header", "header.stamp", "header.stamp.sec",
                      "header.stamp.nanosec"])
    how = rng.choice(["drop", "drop", "null", "string", "number", "dict", "nested"])
    picks = range(len(msgs)) if rng.random() < 0.2 else rng.sample(range(len(msgs)), rng.randint(1, 3))
    for i in picks:
        *parents, last = key.split(".")
        obj = msgs[i]
        for p in parents:
            obj = obj[p]
        if how == "drop":
            del obj[last]
        else:
            obj[last] = {"null": None, "string": "x", "number": 7, "dict": {"a": 1},
                         "nested": [[1.0, 2.0], [3.0]]}[how]
    writers.write_mcap_json(target, rec, msgs)
    return f"json:{how}:{key}"


def sparse_mat(target: Path, rng: random.Random) -> str:
    """The v5 .mat with X (or U) replaced: a sparse matrix (of the data's size, or declaring a
    dense size of gigabytes), a cell of sparse matrices, a struct, or a compressed file whose
    X or U inflates to 8 or 600 MB of zeros past its declared shape (a zlib bomb)."""
    import numpy as np
    import scipy.io
    import scipy.sparse
    import writers

    data = {k: v for k, v in scipy.io.loadmat(target).items() if not k.startswith("__")}
    name = rng.choice(["X", "U"])
    kind = rng.choice(["sparse", "huge", "huge", "cell-huge", "struct", "int", "zlib", "zlib"])
    if kind == "zlib":
        scipy.io.savemat(target, data, do_compression=True)
        writers.pad_compressed_mat(target, name, rng.choice([8 << 20, 600 << 20]))
        return f"mat:zlib:{name}"
    if kind == "sparse":
        data[name] = scipy.sparse.csc_matrix(data[name])
    elif kind in ("huge", "cell-huge"):
        rows, cols = rng.choice([(100_000_000, 7), (7, 100_000), (1_000_000, 1_000)])
        m = scipy.sparse.csc_matrix((np.ones(3), ([0, 1, 2], [0, 1, 2])), shape=(rows, cols))
        data[name] = m if kind == "huge" else np.array([m], dtype=object).reshape(1, 1)
    elif kind == "struct":
        data[name] = {"a": data[name]}
    else:
        data[name] = data[name].astype(np.int64)
    scipy.io.savemat(target, data)
    return f"mat:{kind}:{name}"


def long_line(raw: bytes, rng: random.Random) -> tuple[str, bytes]:
    """A CSV line longer than the line cap of a 1 MB cap (the case runs with CCL_MAX_BYTES=1M):
    one line holding the whole file, or one cell of 1.5 MB, with or without line ends."""
    kind = rng.choice(["one-line", "cell", "cr-only"])
    if kind == "one-line":
        return "long:one-line", raw.replace(b"\n", b",") * 40 + b"1," * 600_000
    if kind == "cr-only":
        return "long:cr-only", raw.replace(b"\n", b"\r")
    lines = raw.split(b"\n")
    k = rng.randrange(1, max(2, len(lines) - 1))
    lines[k] = lines[k] + b"9" * 1_500_000
    return "long:cell", b"\n".join(lines)


#: positions a damaged ROS 1 bag may declare: past the end, beyond any seek, "negative"
#: (a small unsigned value's two's complement), inside the magic, zero
ROS1_POSITIONS = ["past-end", "beyond-seek", "max", "negative", "in-magic", "zero", "at-end"]


def ros1_positions(raw: bytes, rng: random.Random) -> tuple[str, bytes]:
    """A ROS 1 bag with one declared position rewritten: a chunk info record's chunk_pos,
    or the bag header's index_pos."""
    fields = [(name, at + len(name)) for name in (b"chunk_pos=", b"index_pos=")
              for at in _find_all(raw, name)]
    if not fields:
        return byte_mutation(raw, rng)
    name, at = rng.choice(fields)
    kind = rng.choice(ROS1_POSITIONS)
    value = {"past-end": len(raw) + rng.randrange(1, 1 << 20),
             "beyond-seek": (1 << 63) + rng.randrange(1 << 20), "max": (1 << 64) - 1,
             "negative": (1 << 64) - rng.randrange(1, 4096), "in-magic": rng.randrange(1, 13),
             "zero": 0, "at-end": len(raw)}[kind]
    b = bytearray(raw)
    struct.pack_into("<Q", b, at, value)
    return f"ros1-position:{name.decode().rstrip('=')}:{kind}", bytes(b)


def outside_manifest(target: Path, rng: random.Random) -> str:
    """A manifest that names paths outside its folder: ../ in a job's files or out."""
    import yaml

    spec = yaml.safe_load(target.read_text())
    kind = rng.choice(["files", "out", "config", "symlink"])
    job = spec["jobs"][0]
    if kind == "files":  # the same files, named through ../ from the manifest's folder
        job["files"] = [os.path.relpath(p, target.parent) for p in job["files"]]
    elif kind == "out":
        spec["out"] = "../../escaped"
    elif kind == "config":
        job["config"] = os.path.relpath(job["config"], target.parent)
    else:  # a folder inside that is a symlink to the files' folder
        link = target.parent / "data"
        link.symlink_to(Path(job["files"][0]).parent)
        job["files"] = [f"data/{Path(p).name}" for p in job["files"]]
    target.write_text(yaml.safe_dump(spec, sort_keys=False))
    return f"outside:{kind}"


def hostile_mutation(base: dict[str, Any], dst: Path, target: Path, rng: random.Random
                     ) -> tuple[str, dict[str, str]] | None:
    """One of the mutations of issue 20 for this input (None: none applies, or not drawn).
    Returns (mutation, environment of the case)."""
    fmt = base["format"]
    r = rng.random()
    if r < 0.2:
        return special_file(target, rng), {}
    if fmt in ("hdf5", "model", "mat73") and r < 0.55:
        return bomb_dataset(target, rng), {}
    if fmt in ("hdf5", "model", "mat73"):
        mutation, new = damage_attributes(target.read_bytes(), rng)
        target.write_bytes(new)
        return mutation, {}
    if fmt == "mat5":
        return sparse_mat(target, rng), {}
    if fmt == "csv":
        mutation, new = long_line(target.read_bytes(), rng)
        target.write_bytes(new)
        return mutation, {"CCL_MAX_BYTES": SMALL_CAP}
    if fmt == "mcap" and base["name"] == "mcap-json":
        return json_messages(target, rng), {}
    if fmt in ("ros2", "ros2-metadata") and target.name != "metadata.yaml":
        return outside_storage(dst, target, rng), {}
    if fmt == "ros2-metadata":
        storage = next(p for p in sorted(dst.iterdir()) if p.suffix in (".db3", ".mcap"))
        return special_file(storage, rng) + ":storage", {}
    if fmt == "manifest":  # planned with its paths bounded to its folder
        return outside_manifest(target, rng), {BOUNDED: "1"}
    return None


# -- the mutations of issue 28: positions, wide integers, names, wide tables, YAML bombs ------------
#: a placeholder replaced by a 5,000-digit integer in the text (Python cannot print one)
HUGE_INT = "__CCL_FUZZ_HUGE_INT__"
WIDE_INT = "9" * 5000


def _with_huge_int(data: Any, rng: random.Random) -> Any:
    """``data`` with one node (a value, or an item) replaced by :data:`HUGE_INT`."""
    data = copy.deepcopy(data)
    paths = [p for p in _paths(data) if p]
    if not paths:
        return HUGE_INT
    path = rng.choice(paths)
    parent = data
    for key in path[:-1]:
        parent = parent[key]
    parent[path[-1]] = HUGE_INT
    return data


def huge_integer(base: dict[str, Any], target: Path, rng: random.Random) -> str | None:
    """A 5,000-digit integer (beyond Python's 4,300-digit int(str) limit) in a YAML value, a
    JSON attribute of an HDF5 file, a CSV cell or a JSON MCAP message."""
    import yaml

    fmt, sign = base["format"], rng.choice(["", "-"])
    if base.get("yaml"):
        text = yaml.safe_dump(_with_huge_int(yaml.safe_load(target.read_bytes()), rng), sort_keys=False)
        target.write_text(text.replace(HUGE_INT, sign + WIDE_INT))
        return "huge-int:yaml"
    if fmt in ("hdf5", "model"):
        import h5py

        with h5py.File(target, "a") as f:
            found = [(obj, k, _json(obj.attrs[k])) for obj in [f, *_objects(f)] for k in obj.attrs]
            found = [item for item in found if item[2] is not None]
            if not found:
                return None
            obj, key, value = rng.choice(found)
            value = _with_huge_int(value, rng)
            obj.attrs[key] = json.dumps(value).replace(f'"{HUGE_INT}"', sign + WIDE_INT)
        return f"huge-int:attr:{key}"
    if fmt == "csv":
        lines = target.read_text().splitlines()
        i = rng.randrange(1, len(lines))
        cells = lines[i].split(",")
        cells[rng.randrange(len(cells))] = sign + WIDE_INT
        lines[i] = ",".join(cells)
        target.write_text("\n".join(lines) + "\n")
        return "huge-int:csv"
    if fmt == "mcap" and base["name"] == "mcap-json":
        import writers

        rec = writers.joint_recording(n=60, gap_after=30)
        msgs = [writers.msg_dict(rec, i) for i in range(len(rec.t_ns))]
        k = rng.randrange(len(msgs))
        msgs[k] = _with_huge_int(msgs[k], rng)
        raw = [json.dumps(m).replace(f'"{HUGE_INT}"', sign + WIDE_INT).encode() for m in msgs]
        writers.write_mcap_json(target, rec, raw)
        return "huge-int:json-message"
    return None


def _objects(f: Any) -> list[Any]:
    out: list[Any] = []
    f.visititems(lambda name, obj: out.append(obj))
    return out


def _json(value: Any) -> Any:
    """The JSON mapping or list an attribute holds as text, else None."""
    if not isinstance(value, str | bytes):
        return None
    text = value.decode("utf-8", "replace") if isinstance(value, bytes) else value
    if text[:1] not in ("[", "{"):
        return None
    try:
        return json.loads(text)
    except (ValueError, RecursionError):
        return None


def key_bomb(target: Path, rng: random.Random) -> str:
    """A YAML file of 200,000 keys (3.4 MB), block or flow style, or 20,000 under one key of
    the real file."""
    kind = rng.choice(["block", "flow", "inside"])
    if kind == "block":
        target.write_text("data:\n" + "".join(f"  k{i:06d}: {i}\n" for i in range(200_000)))
    elif kind == "flow":
        target.write_text("data: {" + ", ".join(f"k{i:06d}: {i}" for i in range(200_000)) + "}\n")
    else:
        bomb = "".join(f"  k{i}: [{i}, {i}]\n" for i in range(40_000))
        target.write_text(target.read_text() + "bomb:\n" + bomb)
    return f"key-bomb:{kind}"


def duplicate_key(target: Path, rng: random.Random) -> str:
    """A line ``key: ...`` of the YAML file given twice (right after itself, or at the end
    of its mapping)."""
    import re

    lines = target.read_text().splitlines()
    keyed = [i for i, ln in enumerate(lines) if re.match(r"^\s*[A-Za-z_][\w.-]*:", ln)]
    if not keyed:
        return "duplicate-key:none"
    i = rng.choice(keyed)
    lines.insert(i + 1, lines[i])
    target.write_text("\n".join(lines) + "\n")
    return "duplicate-key"


def wide_csv(target: Path, rng: random.Random) -> str:
    """The CSV with thousands of columns no config reads inserted (at the front, the middle or
    the end)."""
    lines = target.read_text().splitlines()
    extra = rng.choice([1_000, 20_000, 20_000, 200_000])
    where = rng.choice(["front", "middle", "end"])
    header = lines[0].split(",")
    at = {"front": 0, "middle": len(header) // 2, "end": len(header)}[where]
    names = [f"unused_{j}" for j in range(extra)]
    rows = []
    for k, line in enumerate(lines):
        cells = line.split(",")
        cells[at:at] = names if k == 0 else ["0.5"] * extra
        rows.append(",".join(cells))
    target.write_text("\n".join(rows) + "\n")
    return f"wide-csv:{extra}:{where}"


def odd_name(dst: Path) -> Path:
    """``dst`` renamed to a name that is not UTF-8 (bytes 0xff 0xfe before its suffix)."""
    new = dst.with_name(os.fsdecode(b"name\xff\xfe" + os.fsencode(dst.suffix)))
    dst.rename(new)
    return new


def round4_mutation(base: dict[str, Any], dst: Path, target: Path, rng: random.Random
                    ) -> tuple[str, Path] | None:
    """One of the mutations of issue 28 for this input: a file name that is not UTF-8 (a
    quarter of them, any input), else what fits its format — ROS 1 chunk and index positions,
    a wide CSV or a 5,000-digit cell, a YAML key bomb, a duplicate key or a 5,000-digit value,
    a 5,000-digit integer in an HDF5 JSON attribute or a JSON message. Returns (mutation, the
    input's path now), or None when nothing fits (a MATLAB file, a binary storage file)."""
    fmt = base["format"]
    if rng.random() < 0.25:
        return "odd-name", odd_name(dst)
    if fmt == "ros1":
        mutation, new = ros1_positions(target.read_bytes(), rng)
        target.write_bytes(new)
        return mutation, dst
    if fmt == "csv":
        return (wide_csv(target, rng) if rng.random() < 0.6 else huge_integer(base, target, rng)), dst
    if base.get("yaml"):
        kind = rng.choice(["key-bomb", "duplicate-key", "huge-int"])
        if kind == "key-bomb":
            return key_bomb(target, rng), dst
        if kind == "duplicate-key":
            return duplicate_key(target, rng), dst
        return huge_integer(base, target, rng), dst
    mutation = huge_integer(base, target, rng)
    return (mutation, dst) if mutation is not None else None


# -- one case ----------------------------------------------------------------------------------------
def make_case(base: dict[str, Any], work: Path, rng: random.Random, hostile: float = 0.0,
              round4: float = 0.0) -> tuple[str, list[str] | None, Path, dict[str, str]]:
    """Copy the base input into ``work``, mutate it, and return (mutation, argv, path, the
    case's environment). ``hostile``: the share of cases given a mutation of issue 20;
    ``round4``: of issue 28 (drawn only when positive, so the other mixes' seeds give the
    cases they gave before)."""
    if work.exists():
        shutil.rmtree(work)
    work.mkdir(parents=True)
    src: Path = base["input"]
    dst = work / src.name
    if src.is_dir():
        shutil.copytree(src, dst)
    else:
        shutil.copy(src, dst)
    target = dst / base["path"].name if src.is_dir() else dst
    raw = target.read_bytes()
    fmt = base["format"]
    env: dict[str, str] = {}
    drawn = hostile_mutation(base, dst, target, rng) if rng.random() < hostile else None
    if drawn is None and round4 > 0 and rng.random() < round4:
        found = round4_mutation(base, dst, target, rng)
        if found is not None:
            drawn, dst = (found[0], {}), found[1]
    r = rng.random()
    if drawn is not None:
        mutation, env = drawn
    elif base.get("yaml") and r < 0.6:
        mutation, new = yaml_mutation(raw, rng)
        target.write_bytes(new)
    elif fmt == "csv" and r < 0.5:
        mutation, new = csv_mutation(raw, rng)
        target.write_bytes(new)
    elif fmt in ("hdf5", "model", "mat73") and r < 0.5:
        mutation = hdf5_mutation(target, rng)
    else:
        mutation, new = byte_mutation(raw, rng)
        target.write_bytes(new)
    out = work / "out"
    if fmt == "manifest":
        return mutation, None, dst, env
    if fmt == "config":
        return mutation, ["run", str(dst), "-o", str(out), "-q"], dst, env
    if fmt == "model":
        r = rng.random()
        if r < 0.25:
            return mutation, ["inspect", str(dst), "--json", "-q"], dst, env
        if r < 0.45:
            return mutation, ["export", str(dst), "-o", str(work / ("e.json" if r < 0.35 else "e.yaml")),
                              "-q"], dst, env
        return mutation, ["predict", str(dst), str(base["data"]), "-o", str(work / "p.csv"), "-q"], dst, env
    cfg = ["-c", str(base["config"])] if base.get("config") else []
    command = rng.choice(["convert", "learn-a", "inspect"])
    if command == "convert":
        return mutation, ["convert", str(dst), "-o", str(work / "c.h5"), "-q", *cfg], dst, env
    if command == "learn-a":
        return mutation, ["learn-a", str(dst), "-o", str(out), "-q", *cfg], dst, env
    return mutation, ["inspect", str(dst), "--json", "-q", *cfg], dst, env


def _child(argv: list[str] | None, manifest: Path, errfile: str, env: dict[str, str] | None = None) -> None:
    """Forked child: run the case, write a verdict line, exit."""
    os.environ.update(env or {})
    fd = os.open(errfile, os.O_WRONLY | os.O_CREAT | os.O_TRUNC)
    os.dup2(fd, 2)
    os.dup2(fd, 1)
    # also under pytest's capture; undecodable text escaped, as Python's own stderr does
    sys.stdout = sys.stderr = open(fd, "w", buffering=1, closefd=False, errors="backslashreplace")
    os.environ["CCL_DEBUG"] = "1"  # internal errors raise: we record where
    code = 0
    try:
        from ccl_cli.errors import CCLError

        if argv is None:
            from ccl_cli.app.batch import plan

            try:
                if "allow_outside" in inspect.signature(plan).parameters:
                    plan(manifest, allow_outside=os.environ.get(BOUNDED) != "1")
                else:  # a version before the bound
                    plan(manifest)
            except CCLError as exc:
                sys.stderr.write(f"ccl: error: {exc.message}\n")
                code = exc.exit_code
        else:
            from ccl_cli.cli import main

            code = main(argv)
    except BaseException as exc:  # noqa: BLE001 - the verdict of the case
        frames = [f for f in traceback.extract_tb(exc.__traceback__) if "ccl_cli" in f.filename]
        where = f"{Path(frames[-1].filename).name}:{frames[-1].lineno}" if frames else "?"
        sys.stderr.write(f"\nINTERNAL {type(exc).__name__} at {where}: {str(exc)[:120]!r}\n")
        code = 99
    sys.stderr.flush()
    sys.stdout.flush()
    os._exit(code if 0 <= code < 256 else 98)


def classify(code: int | None, err: str) -> tuple[str, str]:
    if code is None:
        return "timeout", ""
    if code < 0:
        return "crash", f"signal {-code}"
    if "INTERNAL " in err:
        return "internal", err.split("INTERNAL ", 1)[1].splitlines()[0]
    lines = [ln for ln in err.splitlines() if ln.strip() and not ln.startswith("ccl: dropped")
             and "WARNING" not in ln and not ln.startswith("ccl: removed")]
    if code == 0:
        return "ok", ""
    errors = [ln for ln in lines if ln.startswith("ccl: error: ")]
    if len(errors) != 1 or any("Traceback" in ln for ln in lines):
        return "internal", f"exit {code}, {len(lines)} lines: {lines[-1][:120] if lines else ''}"
    if code == 2:
        return "error", ""
    if code == 1:
        return "exit1", ""
    return "internal", f"exit {code}: {errors[0][:120]}"


def run_case(argv: list[str] | None, manifest: Path, errfile: Path, timeout: float,
             env: dict[str, str] | None = None) -> tuple[int | None, float, float]:
    """(exit code or None on timeout, wall seconds, peak RSS in MB of the case's process)."""
    t0 = time.monotonic()
    pid = os.fork()
    if pid == 0:
        _child(argv, manifest, str(errfile), env)
    while True:
        done, status, usage = os.wait4(pid, os.WNOHANG)
        if done:
            return os.waitstatus_to_exitcode(status), time.monotonic() - t0, usage.ru_maxrss / 1024
        if time.monotonic() - t0 > timeout:
            os.kill(pid, signal.SIGKILL)
            _, _, usage = os.wait4(pid, 0)
            return None, time.monotonic() - t0, usage.ru_maxrss / 1024
        time.sleep(0.002 if time.monotonic() - t0 < 0.2 else 0.02)


def run_subprocess(argv: list[str] | None, manifest: Path, timeout: float,
                   env: dict[str, str] | None = None) -> tuple[int | None, str]:
    ccl = shutil.which("ccl") or str(Path(sys.executable).parent / "ccl")
    cmd = [ccl, *argv] if argv is not None else [ccl, "batch", str(manifest), "-q", "--json"]
    try:
        proc = subprocess.run(cmd, capture_output=True, text=True, timeout=timeout, stdin=subprocess.DEVNULL,
                              env={**os.environ, **(env or {})})
    except subprocess.TimeoutExpired:
        return None, ""
    return proc.returncode, proc.stderr


#: share of cases given a mutation of issue 20 and of issue 28, per mix
MIXES = {"classic": (0.0, 0.0), "hostile": (0.7, 0.0), "even": (0.35, 0.0), "round4": (0.0, 0.7),
         "all": (0.3, 0.3)}


def fuzz(cases: int, seed: int = 0, timeout: float = 20.0, subprocess_cases: int = 0,
         keep: Path | None = None, formats: list[str] | None = None,
         progress: Path | None = None, mix: str = "classic") -> dict[str, Any]:
    """Run ``cases`` mutated inputs (and ``subprocess_cases`` of them through the real
    ``ccl`` executable); return the outcome counts, the internal-error groups, the slowest
    cases and the peak memory of the cases' processes. ``mix``: how many cases get the
    mutations of issue 20 (:data:`MIXES`)."""
    import h5py  # noqa: F401 - loaded once before forking
    import yaml  # noqa: F401

    import ccl_cli.app.batch  # noqa: F401
    import ccl_cli.app.stages  # noqa: F401
    import ccl_cli.cli  # noqa: F401
    import ccl_cli.io  # noqa: F401

    rng = random.Random(seed)
    tmp = Path(tempfile.mkdtemp(prefix="ccl-fuzz-", dir=keep.mkdir(parents=True, exist_ok=True) or keep
                                if keep else None))
    t_start = time.monotonic()
    try:
        bases = build_fixtures(tmp / "fixtures")
        if formats:
            bases = [b for b in bases if b["format"] in formats]
        counts: dict[str, collections.Counter] = collections.defaultdict(collections.Counter)
        groups: collections.Counter = collections.Counter()
        examples: dict[str, str] = {}
        slowest: list[tuple[float, str, str]] = []
        biggest: list[tuple[float, str, str]] = []
        over = {"over_20s": 0, "over_500MB": 0}
        sub_counts: collections.Counter = collections.Counter()
        kinds: collections.Counter = collections.Counter()  # mutations by kind (before the first ':')
        errfile = tmp / "stderr.txt"

        def result(done: int) -> dict[str, Any]:
            total: collections.Counter = collections.Counter()
            for c in counts.values():
                total.update(c)
            return {"benchmark": "fuzz", "cases": done, "seed": seed, "mix": mix, "timeout_s": timeout,
                    "seconds": round(time.monotonic() - t_start, 1),
                    "total": {k: total.get(k, 0) for k in OUTCOMES},
                    "per_format": {f: {k: c.get(k, 0) for k in OUTCOMES} for f, c in sorted(counts.items())},
                    "through_ccl_executable": {k: sub_counts.get(k, 0) for k in OUTCOMES},
                    "mutations": dict(kinds.most_common()),
                    "internal_groups": groups.most_common(60), "examples": examples,
                    "slowest": slowest, "peak_rss_mb": biggest, **over}

        for i in range(cases):
            if progress is not None and i and i % 200 == 0:
                progress.write_text(json.dumps(result(i)) + "\n")
            base = bases[i % len(bases)] if i < len(bases) else rng.choice(bases)
            mutation, argv, dst, env = make_case(base, tmp / "case", rng, *MIXES[mix])
            # manifests through the executable would run whole batches: they go through the
            # planner in-process only
            through_ccl = i < subprocess_cases and argv is not None
            if through_ccl:
                t_case = time.monotonic()
                code, err = run_subprocess(argv, dst, timeout, env)
                seconds, rss = time.monotonic() - t_case, 0.0
            else:
                code, seconds, rss = run_case(argv, dst, errfile, timeout, env)
                err = errfile.read_text(errors="replace") if errfile.exists() else ""
            outcome, detail = classify(code, err)
            counts[base["format"]][outcome] += 1
            kinds[mutation.split(":")[0]] += 1
            if through_ccl:
                sub_counts[outcome] += 1
            slowest = sorted([*slowest, (round(seconds, 2), base["name"], mutation)], reverse=True)[:5]
            biggest = sorted([*biggest, (round(rss, 1), base["name"], mutation)], reverse=True)[:5]
            over["over_20s"] += seconds > 20
            over["over_500MB"] += rss > 500
            if outcome in ("internal", "crash", "timeout"):
                key = f"{base['format']}: {detail}"[:200]
                groups[key] += 1
                if keep is not None and key not in examples:
                    keep.mkdir(parents=True, exist_ok=True)
                    name = f"case_{i}_{base['name']}"
                    shutil.copytree(tmp / "case", keep / name, dirs_exist_ok=True, symlinks=True,
                                    copy_function=_copy_regular)
                    (keep / name / "argv.json").write_text(json.dumps({"argv": argv, "mutation": mutation,
                                                                       "env": env}))
                    examples[key] = str(keep / name)
        return result(cases)
    finally:
        if keep is None:  # with --keep the fixtures stay, so that kept cases can be re-run
            shutil.rmtree(tmp, ignore_errors=True)


def _copy_regular(src: str, dst: str) -> None:
    """Copy a regular file; a FIFO, socket or device is recreated as a note (opening one
    to copy it would block)."""
    if Path(src).is_file():
        shutil.copy2(src, dst)
    else:
        Path(dst + ".special").write_text(f"{src} was not a regular file\n")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--cases", type=int, default=2000)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--timeout", type=float, default=20.0)
    ap.add_argument("--subprocess", type=int, default=0, help="cases run through the real ccl executable")
    ap.add_argument("--keep", type=Path, default=None, help="copy one example per failure group here")
    ap.add_argument("--formats", default=None, help="comma-separated subset of formats")
    ap.add_argument("--progress", type=Path, default=None, help="write partial results here every 200 cases")
    ap.add_argument("--mix", choices=sorted(MIXES), default="classic",
                    help="share of cases given the mutations of issue 20 (bombs, special files, ...) and of "
                         "issue 28 (positions, wide integers, names, wide CSVs, YAML bombs, duplicate keys)")
    args = ap.parse_args()
    result = fuzz(args.cases, args.seed, args.timeout, args.subprocess, args.keep,
                  args.formats.split(",") if args.formats else None, args.progress, args.mix)
    sys.stdout.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    main()
