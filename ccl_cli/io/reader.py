"""The one reader protocol: a recording opened with the ``data`` options.

A :class:`Reader` is made for one path and one :class:`~ccl_cli.io.options.DataOptions`
(checking what it can without reading, e.g. options that do not apply to its format);
:meth:`~Reader.read` turns the recording into a :class:`Recording`, :meth:`~Reader.inspect`
says what it holds (``ccl inspect``). ``open``/``close`` (or ``with``) hold resources a
reader keeps between calls. Two families share the work: formats of time-stamped streams
(CSV, bags, MCAP: :class:`~ccl_cli.io.streams.StreamReader`, which offers ``streams``) and
formats of arrays (HDF5, .mat: the parts of :mod:`ccl_cli.io.arrays`).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path
from types import TracebackType
from typing import Any, ClassVar, Protocol, Self

from ccl_cli.dataset import Demonstrations
from ccl_cli.io.options import DataOptions


@dataclass
class Recording:
    """What a reader read: the demonstrations, the time origin (int64 ns; the dataset's
    ``t`` is seconds since it), and what a canonical file stores beside the data."""

    data: Demonstrations
    time_origin_ns: int = 0
    masks: dict[str, list[int]] | None = None
    provenance: dict[str, Any] | None = None


class Reader(Protocol):
    """One recording read through the ``data`` options."""

    format: ClassVar[str]
    path: Path
    options: DataOptions

    def open(self) -> None: ...

    def close(self) -> None: ...

    def __enter__(self) -> Self: ...

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None: ...

    def read(self) -> Recording:
        """The recording as demonstrations (every problem: one InputError line)."""
        ...

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        """What the recording holds (streams, columns, tree, counts, rates) as a JSON-able
        dict; ``gap`` (seconds) is the pause that splits demonstrations."""
        ...


class ReaderBase:
    """Path, options and context use for the readers (nothing held open by default)."""

    format: ClassVar[str] = ""

    def __init__(self, path: str | Path, options: DataOptions) -> None:
        self.path = Path(path)
        self.options = options

    @property
    def where(self) -> str:
        """The path as messages name it."""
        return str(self.path)

    def open(self) -> None:
        return None

    def close(self) -> None:
        return None

    def __enter__(self) -> Self:
        self.open()
        return self

    def __exit__(self, kind: type[BaseException] | None, exc: BaseException | None,
                 tb: TracebackType | None) -> None:
        self.close()
