"""The ``data`` section of a config → one :class:`~ccl_cli.dataset.Demonstrations`."""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io.files import expand_files, file_hash
from ccl_cli.io.registry import detect_format, open_recording

DATA_KEYS = {"files", "format", "typestore", "state", "action", "time", "demos", "nonfinite",
             "test", "min_samples"}


def load_file(path: Path, data_cfg: dict[str, Any]) -> tuple[Demonstrations, int]:
    """One recording → (Demonstrations, time origin ns)."""
    return open_recording(path, data_cfg).load()


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
    config = config or {}
    fmt = detect_format(path) if (config.get("format") or "auto") == "auto" else config["format"]
    out: dict[str, Any] = {"path": str(path), "format": fmt,
                           "size_bytes": sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
                           if path.is_dir() else path.stat().st_size}
    out.update(open_recording(path, {**config, "format": fmt}).inspect(gap))
    return out
