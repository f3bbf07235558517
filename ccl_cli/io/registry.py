"""The registry of formats: one entry per format, detection from the content, one opener.

Every format is a :class:`Format` entry: a name, a summary, a content test
(:mod:`ccl_cli.io.sniff`) and the module and class of its :class:`~ccl_cli.io.reader.Reader`,
imported on first use so that importing :mod:`ccl_cli.io` stays cheap. Detection looks at
the content (magic bytes, bag directories), not only the suffix; entries are tried in
order, most specific first.
"""

from __future__ import annotations

import importlib
from collections.abc import Callable, Mapping
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ccl_cli.errors import InputError
from ccl_cli.io.options import DataOptions
from ccl_cli.io.reader import Reader
from ccl_cli.io.sniff import is_bag, is_hdf5, is_mat, is_mcap, is_text, read_head


@dataclass(frozen=True)
class Format:
    """A registry entry: ``sniff(path, head)`` says whether ``path`` (first bytes ``head``;
    empty for a directory) is in this format; ``reader`` is ``"module:Class"``."""

    name: str
    summary: str
    sniff: Callable[[Path, bytes], bool]
    reader: str

    def reader_class(self) -> type[Reader]:
        module, _, name = self.reader.partition(":")
        return getattr(importlib.import_module(module), name)


REGISTRY: dict[str, Format] = {fmt.name: fmt for fmt in (
    Format("bag", "ROS 1 .bag file or ROS 2 bag directory (sqlite3/mcap), via rosbags",
           is_bag, "ccl_cli.io.formats.bag:BagReader"),
    Format("mcap", "standalone MCAP (ROS 2 CDR, ROS 1, JSON)", is_mcap, "ccl_cli.io.formats.mcap:McapReader"),
    Format("mat", "MATLAB .mat, v5/v7 (scipy) and v7.3 (HDF5), by variable names",
           is_mat, "ccl_cli.io.formats.mat:MatReader"),
    Format("hdf5", "HDF5: the canonical ccl-demonstrations layout, or any layout via the config",
           is_hdf5, "ccl_cli.io.formats.hdf5:Hdf5Reader"),
    Format("csv", "CSV / text table (header or not, one sample per row or per column)",
           is_text, "ccl_cli.io.formats.csv:CsvReader"),
)}
FORMATS: tuple[str, ...] = tuple(REGISTRY)


def detect_format(path: str | Path) -> str:
    """The name of the first format whose content test accepts ``path``."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    head = b""
    if not path.is_dir():
        head = read_head(path)
        if not head:
            raise InputError(f"{path}: empty file")
    for fmt in REGISTRY.values():
        if fmt.sniff(path, head):
            return fmt.name
    if path.is_dir():
        raise InputError(f"{path}: a directory but not a ROS 2 bag (no metadata.yaml)")
    raise InputError(f"{path}: unknown format (not {', '.join(REGISTRY)})")


def format_of(path: str | Path, options: DataOptions) -> str:
    """``options.format`` when given, else the detected one."""
    return detect_format(path) if options.format == "auto" else options.format


def open_reader(path: str | Path, options: DataOptions | Mapping[str, Any] | None = None) -> Reader:
    """The :class:`~ccl_cli.io.reader.Reader` of ``path`` for the ``data`` options (a
    mapping is validated into :class:`~ccl_cli.io.options.DataOptions`)."""
    options = DataOptions.from_mapping(options)
    return REGISTRY[format_of(path, options)].reader_class()(path, options)
