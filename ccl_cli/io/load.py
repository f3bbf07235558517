"""The ``data`` options and the input files → one dataset; what a recording holds.

:func:`read_dataset` is what every command reads its data with: each file gives one or
more demonstrations (ids renumbered across files); a single canonical file also gives
its stored train/test masks. :func:`inspect_recording` is ``ccl inspect``.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io.files import expand_files, file_hash, given_once
from ccl_cli.io.options import DataOptions
from ccl_cli.io.reader import Recording
from ccl_cli.io.registry import format_of, open_reader
from ccl_cli.io.units import configured, fill_units

Options = DataOptions | Mapping[str, Any] | None


def read_dataset(options: Options, files: Sequence[str | Path] | None = None, base: Path | None = None
                 ) -> tuple[Demonstrations, dict[str, list[int]] | None]:
    """The dataset of ``files`` (else ``options.files``, relative to ``base``) and the
    train/test masks (lists of demo ids) a single canonical file stores, re-cut by the
    ``demos`` options; None otherwise.

    ``metadata`` records per file its path, sha256, what was read and the ids of the
    demonstrations it gave (``demo_ids``), the time origin
    (int64 ns) of the first file and, for a single file that stores one, its provenance.
    A mapping is validated into :class:`DataOptions` (a ``test`` key is ignored). A recording
    given twice (the same file, or the same content) is refused (InputError).
    """
    options = DataOptions.from_mapping(options)
    entries = [str(f) for f in files] if files else options.files
    if not entries:
        raise ConfigError("no input data: give files on the command line or data.files in the config")
    paths = expand_files(entries, None if files else base)
    given_once(paths)
    options = robot_relative_to(options, base)
    recordings: list[Recording] = []
    for path in paths:
        with open_reader(path, options) as reader:
            recordings.append(reader.read())
    parts = [r.data for r in recordings]
    data = parts[0] if len(parts) == 1 else Demonstrations.concatenate(parts)
    fill_units(data, configured(options.state and options.state.units, data.n_state, "data.state"),
               configured(options.action and options.action.units, data.n_action, "data.action"))
    ends = np.cumsum([part.n_samples for part in parts])
    digests = [file_hash(p) for p in paths]
    given_once(paths, digests)
    data.metadata = {"files": [{"path": str(p), "sha256": digest,
                                **{k: v for k, v in part.metadata.items() if k != "source"},
                                "demo_ids": np.unique(data.demo[end - part.n_samples:end]).tolist()}
                               for p, part, end, digest in zip(paths, parts, ends, digests, strict=True)],
                     "time_origin_ns": recordings[0].time_origin_ns}
    single = recordings[0] if len(recordings) == 1 else None
    if single is not None and single.provenance is not None:
        data.metadata["provenance"] = single.provenance
    if data.n_samples < options.min_samples:
        raise InputError(f"only {data.n_samples} samples were read; at least {options.min_samples} "
                         "are needed")
    return data, single.masks if single is not None else None


def robot_relative_to(options: DataOptions, base: Path | None) -> DataOptions:
    """``options`` with a relative robot path of ``state.forward_kinematics`` taken from ``base``
    (the config's folder)."""
    fk = options.state.forward_kinematics if options.state is not None else None
    if base is None or fk is None or not isinstance(fk.robot, str) or Path(fk.robot).is_absolute():
        return options
    fk = fk.model_copy(update={"robot": str(base / fk.robot)})
    return options.model_copy(update={"state": options.state.model_copy(update={"forward_kinematics": fk})})


def load_demonstrations(options: Options, base: Path | None = None,
                        files: Sequence[str | Path] | None = None) -> Demonstrations:
    """:func:`read_dataset` without the masks."""
    return read_dataset(options, files, base)[0]


def inspect_recording(path: str | Path, options: Options = None, gap: float | None = None,
                      base: Path | None = None) -> dict[str, Any]:
    """What a recording holds, for ``ccl inspect``: ``path``, ``format``, ``size_bytes`` and
    the reader's listing (topics with type, count, rate over the active time, fields and
    joint names; or columns, rows and time column; or the HDF5/.mat tree with what the
    options read from it). For streams, ``demos`` (with ``demos_from``, ``gap_s``,
    ``gap_rule``) counts the pieces a split on pauses longer than ``gap`` finds: ``gap``,
    else ``demos.split_on_gap`` of the options, else 5 × the median sampling interval.
    ``base``: the config's folder (a relative robot path of the options is taken from it)."""
    path = Path(path)
    options = robot_relative_to(DataOptions.from_mapping(options), base)
    rule = "--gap"
    if gap is None:
        gap, rule = options.demos.split_on_gap, "data.demos.split_on_gap of the config"
    fmt = format_of(path, options)
    out: dict[str, Any] = {"path": str(path), "format": fmt,
                           "size_bytes": sum(p.stat().st_size for p in path.rglob("*") if p.is_file())
                           if path.is_dir() else path.stat().st_size}
    with open_reader(path, options.model_copy(update={"format": fmt})) as reader:
        out.update(reader.inspect(gap))
    if "gap_s" in out and "gap_rule" not in out:
        out["gap_rule"] = rule
    return out
