"""One reader interface and the registry of formats.

Every format is a :class:`Format` entry: a name, a content sniffer and a factory that
opens a path with the ``data`` section of a config and returns a :class:`Reader`.
A reader turns one recording into :class:`~ccl_cli.dataset.Demonstrations` (``load``)
and summarises it for ``ccl inspect`` (``inspect``). Factories import their
third-party libraries lazily, so importing :mod:`ccl_cli.io` stays cheap.

Detection looks at the content (magic bytes, bag directories), not only the suffix;
entries are tried in registration order, most specific first.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Protocol

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError

HEAD_BYTES = 128


class Reader(Protocol):
    """One recording opened with a ``data`` config section."""

    path: Path

    def load(self) -> tuple[Demonstrations, int]:
        """The demonstrations of the recording and its time origin (int64 ns)."""
        ...

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        """What the recording holds (streams, columns, tree, counts, rates), as a JSON-able
        dict; ``gap`` asks for the demonstrations a split on time gaps would find."""
        ...


@dataclass(frozen=True)
class Format:
    """A registry entry. ``sniff(path, head)`` says whether ``path`` (first bytes
    ``head``; empty for directories) is in this format; ``open(path, data_cfg)``
    returns its reader."""

    name: str
    summary: str
    sniff: Callable[[Path, bytes], bool]
    open: Callable[[Path, dict[str, Any]], Reader]


REGISTRY: dict[str, Format] = {}


def register(fmt: Format) -> Format:
    """Add ``fmt`` (after the entries already registered; a name is registered once)."""
    if fmt.name in REGISTRY:
        raise ValueError(f"format {fmt.name!r} is already registered")
    REGISTRY[fmt.name] = fmt
    return fmt


def format_names() -> tuple[str, ...]:
    return tuple(REGISTRY)


def detect_format(path: str | Path) -> str:
    """The name of the first registered format whose sniffer accepts ``path``."""
    path = Path(path)
    if not path.exists():
        raise InputError(f"{path}: no such file or directory")
    head = b""
    if not path.is_dir():
        try:
            with open(path, "rb") as f:
                head = f.read(HEAD_BYTES)
        except OSError as exc:
            raise InputError(f"{path}: {exc.strerror}") from None
        if not head:
            raise InputError(f"{path}: empty file")
    for fmt in REGISTRY.values():
        if fmt.sniff(path, head):
            return fmt.name
    if path.is_dir():
        raise InputError(f"{path}: a directory but not a ROS 2 bag (no metadata.yaml)")
    raise InputError(f"{path}: unknown format (not {', '.join(REGISTRY)})")


def resolve_format(path: Path, data_cfg: dict[str, Any] | None) -> str:
    """``data.format`` when given (checked against the registry), else the detected one."""
    fmt = (data_cfg or {}).get("format") or "auto"
    if fmt == "auto":
        return detect_format(path)
    if fmt not in REGISTRY:
        raise InputError(f"data.format must be auto or one of {', '.join(REGISTRY)}, got {fmt!r}")
    return fmt


def open_recording(path: str | Path, data_cfg: dict[str, Any] | None = None) -> Reader:
    """The :class:`Reader` of ``path`` for the ``data`` section ``data_cfg``."""
    path = Path(path)
    data_cfg = data_cfg or {}
    fmt = resolve_format(path, data_cfg)
    return REGISTRY[fmt].open(path, data_cfg)


# -- the formats ---------------------------------------------------------------------------
HDF5_MAGIC = b"\x89HDF\r\n\x1a\n"
MCAP_MAGIC = b"\x89MCAP"
BAG1_MAGIC = b"#ROSBAG V2.0"


def _sniff_bag(path: Path, head: bytes) -> bool:
    if path.is_dir():
        return (path / "metadata.yaml").exists()
    if path.name == "metadata.yaml" or head.startswith(BAG1_MAGIC):
        return True
    beside = (path.parent / "metadata.yaml").exists()
    return beside and (head.startswith(MCAP_MAGIC) or head.startswith(b"SQLite format 3"))


def _sniff_hdf5(path: Path, head: bytes) -> bool:
    if head.startswith(HDF5_MAGIC):
        return True
    if b"\x00" in head and not path.is_dir():
        import h5py

        return bool(h5py.is_hdf5(str(path)))  # HDF5 behind a user block
    return False


def _open_stream(fmt: str) -> Callable[[Path, dict[str, Any]], Reader]:
    def open_(path: Path, data_cfg: dict[str, Any]) -> Reader:
        from ccl_cli.io.streamfile import StreamFile

        return StreamFile(path, fmt, data_cfg)

    return open_


def _open_hdf5(path: Path, data_cfg: dict[str, Any]) -> Reader:
    from ccl_cli.io.h5layout import Hdf5File

    return Hdf5File(path, data_cfg)


def _open_mat(path: Path, data_cfg: dict[str, Any]) -> Reader:
    from ccl_cli.io.matfile import MatFile

    return MatFile(path, data_cfg)


def _sniff_mat(path: Path, head: bytes) -> bool:
    from ccl_cli.io.matfile import sniff

    return not path.is_dir() and sniff(path, head)


register(Format("bag", "ROS 1 .bag file or ROS 2 bag directory (sqlite3/mcap), via rosbags",
                _sniff_bag, _open_stream("bag")))
register(Format("mcap", "standalone MCAP (ROS 2 CDR, ROS 1, JSON)",
                lambda path, head: head.startswith(MCAP_MAGIC), _open_stream("mcap")))
register(Format("mat", "MATLAB .mat, v5/v7 (scipy) and v7.3 (HDF5), by variable names",
                _sniff_mat, _open_mat))
register(Format("hdf5", "HDF5: the canonical ccl-demonstrations layout, or any layout via the config",
                _sniff_hdf5, _open_hdf5))
register(Format("csv", "CSV / text table (header or not, one sample per row or per column)",
                lambda path, head: not path.is_dir() and b"\x00" not in head, _open_stream("csv")))
