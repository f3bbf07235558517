"""The bounds of every read: regular files only, paths that stay in their folder, and one
cap on what one object of a file may claim.

* :func:`check_claim` — every reader checks the size an object *declares* (a dataset's
  shape, a sparse matrix's dense size, a message, a text line) before it allocates
  anything for it: over :func:`max_bytes` (``CCL_MAX_BYTES``, default 2 GiB; ``512M``,
  ``4G`` and plain byte counts are understood) it is refused with one line naming the
  object and its declared size. A claim far beyond what the file could hold
  (:data:`MAX_EXPANSION` bytes per byte of file, past 64 MiB: a decompression bomb, or
  a shape no data was ever written for) is refused too.
* :func:`check_span` — every position a file declares (a chunk, an index record) lies
  inside the file before it is sought.
* :func:`open_regular` / :func:`regular_file` — only regular files are opened: a FIFO,
  device or socket would block a read forever or never end; the type is checked before
  the open, and again on the open descriptor (opened non-blocking, so a FIFO swapped in
  between cannot block either).
* :func:`inside` — a path one file names (a ROS 2 bag's storage files, a manifest's jobs)
  stays inside that file's folder once ``..`` and symlinks are resolved, unless the user
  allows it.

A leaf: it imports only :mod:`ccl_cli.errors`.
"""

from __future__ import annotations

import math
import os
import re
import stat
from pathlib import Path
from typing import IO

from ccl_cli.errors import InputError

#: the default cap on the bytes one object may claim
DEFAULT_MAX_BYTES = 2 << 30
#: a claim may not exceed this many bytes per byte of file (past :data:`SMALL_CLAIM`)
MAX_EXPANSION = 1000
#: claims up to this size are never compared with the file's size
SMALL_CLAIM = 64 << 20
#: the longest text line read (CSV, text matrices): bounded by the cap too
MAX_LINE_BYTES = 64 << 20
_UNITS = {"": 1, "K": 1 << 10, "M": 1 << 20, "G": 1 << 30, "T": 1 << 40}


def max_bytes() -> int:
    """The cap on one object's declared size: ``CCL_MAX_BYTES`` (bytes, or a number with a
    K/M/G/T suffix), else :data:`DEFAULT_MAX_BYTES`."""
    raw = os.environ.get("CCL_MAX_BYTES", "").strip()
    if not raw:
        return DEFAULT_MAX_BYTES
    m = re.fullmatch(r"(\d+(?:\.\d+)?)\s*([KMGT]?)(?:i?B)?", raw, re.IGNORECASE)
    if m is None or float(m.group(1)) <= 0:
        raise InputError(f"CCL_MAX_BYTES={raw!r}: give a positive size such as 2G, 512M or 1000000")
    return int(float(m.group(1)) * _UNITS[m.group(2).upper()])


def max_line_bytes() -> int:
    """The longest text line read: :data:`MAX_LINE_BYTES`, or the cap when it is smaller."""
    return min(MAX_LINE_BYTES, max_bytes())


def _size(n: int) -> str:
    for unit, scale in (("TiB", 1 << 40), ("GiB", 1 << 30), ("MiB", 1 << 20), ("KiB", 1 << 10)):
        if n >= scale:
            return f"{n / scale:.3g} {unit}"
    return f"{n} bytes"


def check_claim(where: str, what: str, shape: tuple[int, ...] | int, itemsize: int = 8,
                file_bytes: int | None = None) -> int:
    """Refuse an object whose declared size is over the cap (or, given ``file_bytes``, far
    beyond what the file holds) before anything is allocated for it. ``shape``: the
    declared shape (or a byte count with ``itemsize`` 1); ``itemsize``: the bytes per
    element once read (8: float64). Returns the declared bytes."""
    dims = (shape,) if isinstance(shape, int) else tuple(shape)
    if any(int(d) < 0 for d in dims):
        raise InputError(f"{where}: {what} declares a negative size {dims}; damaged file?")
    nbytes = math.prod(int(d) for d in dims) * itemsize  # Python ints: no overflow
    declared = "×".join(map(str, dims)) if not isinstance(shape, int) else f"{shape} bytes"
    cap = max_bytes()
    if nbytes > cap:
        raise InputError(f"{where}: {what} declares {declared} ({_size(nbytes)}), over the cap of "
                         f"{_size(cap)} per object (CCL_MAX_BYTES); refused before reading")
    if file_bytes is not None and nbytes > SMALL_CLAIM and nbytes > MAX_EXPANSION * file_bytes:
        raise InputError(f"{where}: {what} declares {declared} ({_size(nbytes)}), far more than the "
                         f"file holds ({_size(file_bytes)}); refused before reading")
    return nbytes


class OutsideFile(InputError):
    """A position a file declares lies outside it: the file is damaged (no other reader of
    it would do better)."""


def check_span(where: str, what: str, start: int, stop: int, size: int, within: str = "") -> None:
    """Refuse a span [start, stop) a file declares (a record's position and length) that does
    not lie inside its first ``size`` bytes (``within`` names them; default: the file's) — a
    position past the end, a negative one, one beyond any seek — before anything is sought
    or read there."""
    if not 0 <= start <= stop <= size:
        at = f"byte {start}" if start == stop else f"bytes [{start}, {stop})"
        within = within or f"the file ({size} bytes)"
        raise OutsideFile(f"{where}: {what} is declared at {at}, outside {within}; damaged file?")


# -- regular files ----------------------------------------------------------------------------
def _kind(mode: int) -> str:
    for test, name in ((stat.S_ISFIFO, "a FIFO"), (stat.S_ISCHR, "a character device"),
                       (stat.S_ISBLK, "a block device"), (stat.S_ISSOCK, "a socket"),
                       (stat.S_ISDIR, "a folder")):
        if test(mode):
            return name
    return "not a regular file"


def _refuse(path: str | Path, mode: int, what: str) -> InputError:
    return InputError(f"{path}: {what} is {_kind(mode)}, not a regular file; ccl reads only regular files")


def regular_file(path: str | Path, what: str = "the file") -> os.stat_result:
    """``os.stat`` of ``path`` when it is a regular file (symlinks followed); a missing
    path, a FIFO, device, socket or folder is one InputError line. Never opens it."""
    try:
        st = os.stat(path)
    except FileNotFoundError:
        raise InputError(f"{path}: no such file") from None
    except OSError as exc:
        raise InputError(f"{path}: {exc.strerror or type(exc).__name__}") from None
    if not stat.S_ISREG(st.st_mode):
        raise _refuse(path, st.st_mode, what)
    return st


def open_regular(path: str | Path, what: str = "the file") -> IO[bytes]:
    """``path`` opened for binary reading, after :func:`regular_file`; opened non-blocking
    and checked again on the descriptor (a FIFO swapped in meanwhile is refused, not waited
    on)."""
    regular_file(path, what)
    try:
        fd = os.open(path, os.O_RDONLY | getattr(os, "O_NONBLOCK", 0) | getattr(os, "O_CLOEXEC", 0))
    except OSError as exc:
        raise InputError(f"{path}: {exc.strerror or type(exc).__name__}") from None
    try:
        st = os.fstat(fd)
        if not stat.S_ISREG(st.st_mode):
            raise _refuse(path, st.st_mode, what)
        if hasattr(os, "set_blocking"):
            os.set_blocking(fd, True)
        return os.fdopen(fd, "rb")
    except BaseException:
        os.close(fd)
        raise


# -- paths named by files ---------------------------------------------------------------------
def inside(folder: str | Path, path: str | Path, named_by: str, allow: bool = False,
           flag: str = "data.allow_outside: true") -> Path:
    """``path`` (relative to ``folder``, or absolute) resolved — ``..`` and symlinks — and
    checked to lie inside ``folder`` (resolved); outside it is one InputError line naming
    where it leads, unless ``allow``. Returns the resolved path."""
    folder = Path(folder).resolve()
    given = Path(path)
    full = given if given.is_absolute() else folder / given
    try:
        resolved = full.resolve()
    except (OSError, RuntimeError) as exc:  # a symlink loop
        raise InputError(f"{full}: named by {named_by}, cannot be resolved ({exc})") from None
    if allow or resolved == folder or folder in resolved.parents:
        return resolved
    via = " through a symlink" if resolved != Path(os.path.abspath(full)) else ""
    raise InputError(f"{named_by} names {str(given)!r}, which leads{via} to {resolved}, outside "
                     f"{folder}; refused ({flag} allows it)")
