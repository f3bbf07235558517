"""Readers of demonstration recordings, one per format behind one interface.

``detect_format`` looks at the content (magic bytes, bag directories), not only the
suffix. ``load_demonstrations`` turns the ``data`` section of a config into one
:class:`~ccl_cli.dataset.Demonstrations`. Formats: canonical HDF5, CSV, ROS 1 bag,
ROS 2 bag directory (sqlite3/mcap), standalone MCAP (ROS 2 CDR, ROS 1, JSON).
"""

from __future__ import annotations

import functools
import glob
import hashlib
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io.assemble import (
    align,
    check_increasing,
    drop_nonfinite,
    local_polynomial_derivative,
    resegment,
    segment_ids,
)
from ccl_cli.io.streams import Stream, StreamSpec

FORMATS = ("hdf5", "csv", "bag", "mcap")
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
MCAP_MAGIC = b"\x89MCAP"
BAG1_MAGIC = b"#ROSBAG V2.0"
DATA_KEYS = {"files", "format", "typestore", "state", "action", "time", "demos", "nonfinite",
             "test", "min_samples"}


def detect_format(path: str | Path) -> str:
    """``hdf5``, ``csv``, ``bag`` (ROS 1 file or ROS 2 directory) or ``mcap``."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    if path.is_dir():
        if (path / "metadata.yaml").exists():
            return "bag"
        raise InputError(f"{path}: a directory but not a ROS 2 bag (no metadata.yaml)")
    if path.name == "metadata.yaml":
        return "bag"
    try:
        with open(path, "rb") as f:
            head = f.read(16)
    except OSError as exc:
        raise InputError(f"{path}: {exc.strerror}") from None
    if head.startswith(HDF5_MAGIC):
        return "hdf5"
    if head.startswith(MCAP_MAGIC):
        if (path.parent / "metadata.yaml").exists():
            return "bag"
        return "mcap"
    if head.startswith(BAG1_MAGIC):
        return "bag"
    if head.startswith(b"SQLite format 3") and (path.parent / "metadata.yaml").exists():
        return "bag"
    if not head:
        raise InputError(f"{path}: empty file")
    if b"\x00" in head:
        import h5py

        if h5py.is_hdf5(str(path)):  # HDF5 with a user block
            return "hdf5"
        raise InputError(f"{path}: unknown format (not HDF5, CSV, ROS bag or MCAP)")
    return "csv"


def open_reader(path: str | Path, fmt: str | None = None, config: dict[str, Any] | None = None):
    """The reader object of ``path`` (CSV, bag or MCAP)."""
    from ccl_cli.io.bag import BagReader
    from ccl_cli.io.csvfile import CsvReader
    from ccl_cli.io.mcapfile import McapReader

    config = config or {}
    path = Path(path)
    fmt = fmt if fmt and fmt != "auto" else detect_format(path)
    if fmt == "csv":
        tcfg = config.get("time") or {}
        return CsvReader(path, tcfg.get("column"), tcfg.get("unit"), tcfg.get("rate"),
                         tcfg.get("delimiter"))
    if fmt == "bag":
        return BagReader(path, config.get("typestore"))
    if fmt == "mcap":
        return McapReader(path)
    raise InputError(f"{path}: format {fmt!r} has no stream reader")


def expand_files(files: list[str] | str, base: Path | None = None) -> list[Path]:
    """Paths and globs → existing paths, in the order given (globs sorted)."""
    if isinstance(files, str | Path):
        files = [str(files)]
    out: list[Path] = []
    for entry in files:
        p = Path(entry)
        if base is not None and not p.is_absolute():
            p = base / p
        if any(ch in str(entry) for ch in "*?["):
            matches = sorted(glob.glob(str(p)))
            if not matches:
                raise InputError(f"{entry}: no files match")
            out += [Path(m) for m in matches]
        else:
            if not p.exists():
                raise InputError(f"{p}: no such file or directory")
            out.append(p)
    if not out:
        raise InputError("no input files")
    return out


def file_hash(path: Path) -> str:
    """sha256 of a file, or of a bag directory's files in name order.

    Digests are remembered for the process, keyed on every file's path, size and
    modification time, so an unchanged input is read once however many callers ask
    (a batch job's content key, then the run's provenance).
    """
    path = Path(path)
    paths = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    key = tuple((str(p.resolve()), p.stat().st_size, p.stat().st_mtime_ns) for p in paths)
    return _sha256_of(key)


@functools.lru_cache(maxsize=1024)
def _sha256_of(key: tuple[tuple[str, int, int], ...]) -> str:
    h = hashlib.sha256()
    for name, _, _ in key:
        with open(name, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()


def _clean(stream: Stream, spec: StreamSpec, nonfinite: str) -> Stream:
    where = f"{stream.source} ({spec.describe()})"
    stream.t_ns, stream.values = drop_nonfinite(stream.t_ns, stream.values, nonfinite, where)
    if len(stream.t_ns) == 0:
        raise InputError(f"{where}: no samples left")
    check_increasing(stream.t_ns, where)
    return stream


def load_file(path: Path, data_cfg: dict[str, Any]) -> tuple[Demonstrations, int]:
    """One recording → (Demonstrations, time origin ns)."""
    fmt = data_cfg.get("format") or "auto"
    if fmt not in ("auto", *FORMATS):
        raise InputError(f"data.format must be auto or one of {', '.join(FORMATS)}, got {fmt!r}")
    fmt = detect_format(path) if fmt == "auto" else fmt
    if fmt == "hdf5":
        from ccl_cli.io.hdf5 import read_demonstrations

        data, info = read_demonstrations(path)
        data, _ = resegment(data, data_cfg.get("demos"), str(path))
        return data, info["time_origin_ns"]
    state_spec = StreamSpec.from_config(data_cfg.get("state"))
    if state_spec is None:
        raise InputError(f"{path}: data.state is required for {fmt} input "
                         "(e.g. state: {topic: /joint_states, field: position})")
    reader = open_reader(path, fmt, data_cfg)
    nonfinite = data_cfg.get("nonfinite", "drop")
    action_cfg = data_cfg.get("action") or {"derive": "state"}
    derive = action_cfg.get("derive") if isinstance(action_cfg, dict) else None
    specs = [state_spec] if derive is not None else [state_spec, StreamSpec.from_config(action_cfg)]
    streams = [_clean(s, sp, nonfinite) for s, sp in zip(reader.read_many(specs), specs, strict=True)]
    state = streams[0]
    t_ns = state.t_ns
    X = state.values
    meta: dict[str, Any] = {"source": str(path), "format": fmt, "state": state.meta}
    if derive is None:
        action_spec = specs[1]
        action = streams[1]
        U, inside = align(t_ns, action.t_ns, action.values)
        if not inside.any():
            raise InputError(f"{path}: the action stream ({action_spec.describe()}) does not overlap "
                             "the state stream in time")
        dropped = int((~inside).sum())
        if dropped:
            t_ns, X = t_ns[inside], X[inside]
        action_names = action.names
        meta["action"] = {**action.meta, "aligned": "linear interpolation onto state stamps",
                          "dropped_outside_span": dropped}
    else:
        if derive != "state":
            raise InputError(f"data.action.derive must be 'state', got {derive!r}")
        U = None
        action_names = [f"d{n}/dt" for n in state.names]
        meta["action"] = {"derived": "local polynomial", "window": action_cfg.get("window", 9),
                          "order": action_cfg.get("order", 2)}
    t_s = (t_ns - t_ns[0]) / 1e9
    demo = segment_ids(t_s, data_cfg.get("demos"), str(path))
    keep = demo >= 0
    if not keep.all():  # samples outside every demos.range
        t_ns, t_s, X, demo = t_ns[keep], t_s[keep], X[keep], demo[keep]
    if U is None:
        U = local_polynomial_derivative(t_s, X, demo, int(action_cfg.get("window", 9)),
                                        int(action_cfg.get("order", 2)))
    elif not keep.all():
        U = U[keep]
    data = Demonstrations(X=X, U=U, demo=demo, t=(t_ns - t_ns[0]) / 1e9,
                          state_names=state.names, action_names=action_names, metadata=meta)
    return data, int(t_ns[0])


def load_demonstrations(data_cfg: dict[str, Any], base: Path | None = None,
                        files: list[str] | None = None) -> Demonstrations:
    """The ``data`` section of a config (and optional file list overriding it) → one dataset.

    Each file gives one or more demonstrations; ids are renumbered across files.
    ``metadata`` records the files, their sha256 and what was read.
    """
    unknown = set(data_cfg) - DATA_KEYS
    if unknown:
        raise InputError(f"unknown data option(s): {', '.join(sorted(unknown))}")
    paths = expand_files(files if files else data_cfg.get("files") or [], base)
    parts, origins = [], []
    for path in paths:
        part, origin = load_file(path, data_cfg)
        parts.append(part)
        origins.append(origin)
    data = parts[0] if len(parts) == 1 else Demonstrations.concatenate(parts)
    data.metadata = {"files": [{"path": str(p), "sha256": file_hash(p), **{k: v for k, v in
                                part.metadata.items() if k != "source"}}
                               for p, part in zip(paths, parts, strict=True)],
                     "time_origin_ns": origins[0]}
    min_samples = int(data_cfg.get("min_samples", 2))
    if data.n_samples < min_samples:
        raise InputError(f"only {data.n_samples} samples were read; at least {min_samples} are needed")
    return data


def inspect_path(path: str | Path, config: dict[str, Any] | None = None,
                 gap: float | None = None) -> dict[str, Any]:
    """Summary of a recording: format, topics/columns with types, counts and rates,
    time span, and the demonstrations a gap split would find (as ``ros2 bag info``)."""
    path = Path(path)
    fmt = detect_format(path)
    out: dict[str, Any] = {"path": str(path), "format": fmt,
                           "size_bytes": sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
                           if path.is_dir() else path.stat().st_size}
    if fmt == "hdf5":
        from ccl_cli.io.hdf5 import is_canonical, read_demonstrations

        if not is_canonical(path):
            raise InputError(f"{path}: HDF5 but not a ccl-demonstrations file; convert it first")
        data, info = read_demonstrations(path)
        counts = np.bincount(data.demo)
        out.update({"samples": data.n_samples, "demos": int(data.n_demos),
                    "state_names": data.state_names, "action_names": data.action_names,
                    "samples_per_demo": counts.tolist(), "truth": sorted(data.truth),
                    "masks": {k: len(v) for k, v in info["masks"].items()},
                    "duration_s": float(sum(np.ptp(data.t[data.demo == d]) for d in data.demo_ids))})
        return out
    reader = open_reader(path, fmt, config)
    info = reader.inspect()
    span = (info["end_ns"] - info["start_ns"]) / 1e9
    out.update({"start_ns": info["start_ns"], "end_ns": info["end_ns"], "duration_s": span})
    if "topics" in info:
        for topic in info["topics"].values():
            topic["rate_hz"] = (topic["count"] - 1) / span if span > 0 and topic["count"] > 1 else None
        out["topics"] = info["topics"]
    else:
        out.update({k: info[k] for k in ("columns", "rows", "time_column")})
        if info["rows"] > 1 and span > 0:
            out["rate_hz"] = (info["rows"] - 1) / span
    if gap is not None and config and config.get("state"):
        stream = reader.read(StreamSpec.from_config(config["state"]))
        ids = segment_ids((stream.t_ns - stream.t_ns[0]) / 1e9, {"split_on_gap": gap}, str(path))
        out["demos"] = int(ids.max()) + 1
    return out
