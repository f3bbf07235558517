"""Opening HDF5 files as data, nothing more.

Every HDF5 file ccl reads (canonical demonstrations, models, foreign HDF5 / MATLAB v7.3
readers) goes through :func:`open_hdf5`, which

1. refuses, before any value is read, external links, dangling soft links,
   datasets with external storage (``H5Pget_external_count`` > 0) and virtual
   datasets (:func:`check_tree`) — a file never makes ccl read another file;
2. protects against libhdf5 hanging or crashing on a damaged file. Measured on
   byte-mutated model and data files (``benchmarks/fuzz.py``): about 1 case in 170
   never returned from libhdf5, always while reading a variable-length string
   (corrupt global heap). Files ccl writes carry a content hash in their user block
   (:func:`create_hdf5`: ``\\0ccl-sha256:<hex of every byte after the block>``); when it
   matches, the file is exactly what ccl wrote and is opened directly. Any other file
   (foreign, edited with h5py, damaged) is first parsed in a child process with a
   time limit (:func:`probe`): every attribute, every string dataset and every
   dataset up to ``PROBE_BYTES`` is read there. The hangs measured are CPU-bound loops,
   so the limit is CPU time (``CPU_LIMIT``, via ``RLIMIT_CPU``: robust on a loaded
   machine where wall time is not), with a wall-clock backstop (``TIMEOUT``). A child
   over either limit, or killed by a signal, means the file is refused: one line, exit 2.

Typed accessors (:func:`attr_str`, :func:`attr_int`, :func:`attr_float`,
:func:`attr_strings`, :func:`numeric`) turn every attribute and dataset into a checked
Python/NumPy value or an :class:`~ccl_cli.errors.InputError` naming the file and object.
"""

from __future__ import annotations

import contextlib
import faulthandler
import functools
import hashlib
import json
import math
import os
import signal
import subprocess
import sys
import threading
import time
from collections.abc import Iterator
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import InputError

#: user-block size reserved in files ccl writes (HDF5 requires a power of two ≥ 512)
USERBLOCK = 512
SEAL = b"\x00ccl-sha256:"
#: CPU seconds a foreign file may take to be parsed in the child process (a normal
#: probe takes well under 0.1 s), and the wall-clock backstop
CPU_LIMIT = int(os.environ.get("CCL_HDF5_CPU_LIMIT", "2"))
TIMEOUT = float(os.environ.get("CCL_HDF5_TIMEOUT", "60"))
#: datasets up to this many bytes are read in the child (larger ones: metadata only)
PROBE_BYTES = 64 << 20
#: a dataset may not claim more than this many bytes per byte of file (decompression bombs)
MAX_EXPANSION = 1000
MAX_OBJECTS = 100_000


# -- writing ---------------------------------------------------------------------------------
def _digest(path: Path) -> str:
    h = hashlib.sha256()
    with open(path, "rb") as f:
        f.seek(USERBLOCK)
        for block in iter(lambda: f.read(1 << 20), b""):
            h.update(block)
    return h.hexdigest()


def seal(path: str | Path) -> None:
    """Write the content hash of ``path`` (created with ``userblock_size=USERBLOCK``)
    into its user block."""
    path = Path(path)
    head = SEAL + _digest(path).encode() + b"\n"
    with open(path, "r+b") as f:
        f.write(head + b"\x00" * (USERBLOCK - len(head)))


@contextlib.contextmanager
def create_hdf5(path: str | Path, force: bool = False) -> Iterator[Any]:
    """An ``h5py.File`` written atomically at ``path`` and sealed with its content hash."""
    import h5py

    from ccl_cli.io.atomic import atomic_path

    with atomic_path(path, force=force) as tmp:
        with h5py.File(tmp, "w", userblock_size=USERBLOCK) as f:
            yield f
        seal(tmp)


def sealed(path: str | Path) -> bool:
    """True when ``path`` carries a ccl content hash that matches its content."""
    path = Path(path)
    try:
        with open(path, "rb") as f:
            head = f.read(len(SEAL) + 64)
    except OSError:
        return False
    if not head.startswith(SEAL) or len(head) != len(SEAL) + 64:
        return False
    st = path.stat()
    return _sealed(str(path.resolve()), st.st_size, st.st_mtime_ns, head[len(SEAL):].decode("latin-1"))


@functools.lru_cache(maxsize=256)
def _sealed(path: str, size: int, mtime_ns: int, claimed: str) -> bool:
    return _digest(Path(path)) == claimed


# -- the child-process probe ---------------------------------------------------------------
def _walk(f) -> None:
    """What the probe does: structure check, then read every attribute and every
    dataset that is small enough (values discarded)."""
    import h5py

    check_tree(f, "")
    budget = PROBE_BYTES

    def attrs(obj) -> None:
        for key in obj.attrs:
            obj.attrs[key]

    attrs(f)

    def each(name: str, obj) -> None:
        nonlocal budget
        attrs(obj)
        if isinstance(obj, h5py.Dataset):
            nbytes = obj.size * obj.dtype.itemsize
            if (obj.dtype.kind == "O" and obj.size <= 1_000_000) or nbytes <= budget:
                budget -= nbytes
                obj[()]

    f.visititems(each)


def _probe_child(path: str, cpu_limit: int = CPU_LIMIT) -> None:
    """Child side: parse the file; any Python exception is fine (the parent will meet
    it again, and report it), only a hang or a crash of libhdf5 matters."""
    import resource

    import h5py

    resource.setrlimit(resource.RLIMIT_CPU, (cpu_limit, cpu_limit + 1))

    with h5py.File(path, "r") as f:
        _walk(f)


def _wait(pid: int, timeout: float) -> int | None:
    """Exit code of child ``pid`` (negative: killed by that signal), None on timeout."""
    t0 = time.monotonic()
    try:
        while time.monotonic() - t0 < timeout:
            done, status = os.waitpid(pid, os.WNOHANG)
            if done:
                return os.waitstatus_to_exitcode(status)
            time.sleep(0.002 if time.monotonic() - t0 < 0.1 else 0.02)
    except BaseException:
        os.kill(pid, signal.SIGKILL)
        os.waitpid(pid, 0)
        raise
    os.kill(pid, signal.SIGKILL)
    os.waitpid(pid, 0)
    return None


#: files (by :func:`_identity`) whose probe passed in this process
_PROBED: set[tuple[str, int, int, int]] = set()
#: files (by :func:`_identity`) whose tree passed :func:`check_tree` in this process (a
#: canonical input is opened twice: the format check, then the read; a batch job hashes
#: and reads the same file)
_CHECKED: set[tuple[str, int, int, int]] = set()


def _identity(path: Path) -> tuple[str, int, int, int]:
    """(resolved path, inode, size, mtime in ns): any edit of the file changes it."""
    st = path.stat()
    return str(path.resolve()), st.st_ino, st.st_size, st.st_mtime_ns


def probe(path: Path, timeout: float = TIMEOUT, cpu_limit: int = CPU_LIMIT) -> None:
    """Parse ``path`` in a child process first; refuse it if libhdf5 hangs or crashes there.

    A fork of this process when it runs one thread (fast: h5py is already loaded);
    otherwise a fresh interpreter (forking a threaded process could deadlock the child).
    """
    import h5py  # noqa: F401 - loaded before the fork, so the child does not import it

    where = str(path)
    if hasattr(os, "fork") and threading.active_count() == 1:
        pid = os.fork()
        if pid == 0:  # child: never returns into the caller's code
            try:
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
                faulthandler.disable()  # a crash here is reported by the parent, in one line
                _probe_child(str(path), cpu_limit)
            finally:
                os._exit(0)
        code = _wait(pid, timeout)
    else:
        cmd = [sys.executable, "-c", "import sys; from ccl_cli.io.h5safe import _probe_child; "
               "_probe_child(sys.argv[1], int(sys.argv[2]))", str(path), str(cpu_limit)]
        try:
            code = subprocess.run(cmd, timeout=timeout, stdin=subprocess.DEVNULL,
                                  stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL).returncode
        except subprocess.TimeoutExpired:
            code = None
    if code is None or code == -signal.SIGXCPU:
        limit = f"{timeout:g} s" if code is None else f"{cpu_limit} s of CPU time"
        raise InputError(f"{where}: libhdf5 did not finish parsing the file within {limit} "
                         "(damaged HDF5?); refused")
    if code < 0:
        raise InputError(f"{where}: libhdf5 crashed parsing the file (signal {-code}; damaged HDF5?); "
                         "refused")


# -- opening ---------------------------------------------------------------------------------
def open_hdf5(path: str | Path, what: str = "data file", timeout: float | None = None):
    """An ``h5py.File`` (read-only) for ``path`` after the checks of this module.

    ``what`` names the file in messages ("model file", "MATLAB file", ...). Raises
    :class:`InputError` for a missing/unreadable file, a hang or crash of libhdf5 in the
    probe, and anything :func:`check_tree` refuses. The caller closes the file.
    """
    import h5py

    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise InputError(f"{where}: no such {what}")
    key = _identity(path)
    if key not in _PROBED and not sealed(path):
        # one probe per file version and process (a run opens a file twice)
        probe(path, TIMEOUT if timeout is None else timeout)
        _PROBED.add(key)
    try:
        f = h5py.File(path, "r")
    except (OSError, ValueError, RuntimeError) as exc:
        raise InputError(f"{where}: cannot open as HDF5 {what} ({_first(exc)})") from None
    if key in _CHECKED:  # this version of the file passed check_tree in this process
        return f
    try:
        check_tree(f, where)
    except BaseException:
        f.close()
        raise
    _CHECKED.add(key)
    return f


def check_tree(f, where: str) -> None:
    """Refuse external links, dangling soft links, external-storage and virtual datasets
    anywhere under ``f`` (an open ``h5py.File``). Reads metadata only, never a value.

    Walks the link table with h5py's low-level API (one libhdf5 visit collecting
    (name, link type), then one ``H5Oopen`` per hard link): ~10× faster than the
    high-level ``visititems_links``, which builds a Python object per link.
    """
    from h5py import h5d, h5l, h5o

    links: list[tuple[bytes, int]] = []

    def collect(name: bytes, info) -> int | None:
        links.append((name, info.type))
        return 1 if len(links) > MAX_OBJECTS else None  # a non-None value stops the visit

    try:
        f.id.links.visit(collect, info=True)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError, SystemError) as exc:
        # SystemError: a lookup failed inside libhdf5's visit callback
        cause = exc.__cause__ or exc.__context__ if isinstance(exc, SystemError) else exc
        raise InputError(f"{where}: damaged HDF5 structure ({_first(cause or exc)})") from None
    if len(links) > MAX_OBJECTS:
        raise InputError(f"{where}: more than {MAX_OBJECTS} objects; refused")
    for raw, kind in links:
        name = raw.decode("utf-8", "replace")
        try:
            if kind == h5l.TYPE_EXTERNAL:
                link = f.get(name, getlink=True)
                raise InputError(f"{where}: /{name} is an external link to {link.filename}:{link.path}; "
                                 "ccl reads nothing outside the file")
            if kind == h5l.TYPE_SOFT:
                if not f.id.links.exists(raw) or f.get(name) is None:
                    target = f.get(name, getlink=True).path
                    raise InputError(f"{where}: /{name} is a soft link to {target}, which does not exist")
                continue
            if kind != h5l.TYPE_HARD:
                raise InputError(f"{where}: /{name} is a user-defined link; ccl reads nothing outside "
                                 "the file")
            obj = h5o.open(f.id, raw)
            if isinstance(obj, h5d.DatasetID):
                dcpl = obj.get_create_plist()
                if dcpl.get_layout() == h5d.VIRTUAL:
                    raise InputError(f"{where}: /{name} is a virtual dataset (its data lives in other "
                                     "files); ccl reads nothing outside the file")
                if dcpl.get_external_count() > 0:
                    raise InputError(f"{where}: /{name} stores its data in external files; ccl reads "
                                     "nothing outside the file")
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            raise InputError(f"{where}: damaged HDF5 structure at /{name} ({_first(exc)})") from None


# -- typed access ------------------------------------------------------------------------------
_MISSING = object()


def _first(exc: BaseException) -> str:
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _attr(attrs, key: str, where: str, default: Any) -> Any:
    try:
        if key not in attrs:
            if default is _MISSING:
                raise InputError(f"{where}: attribute {key!r} is missing")
            return default
        return attrs[key]
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: attribute {key!r} cannot be read ({_first(exc)})") from None


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array {value.dtype} {value.shape}"
    return f"{type(value).__name__} {value!r}"[:80]


def _as_str(value: Any) -> str | None:
    if isinstance(value, bytes | np.bytes_):
        try:
            return bytes(value).decode("utf-8")
        except UnicodeDecodeError:
            return None
    if isinstance(value, str):
        return str(value)
    return None


def attr_str(attrs, key: str, where: str, default: Any = _MISSING) -> str:
    """A scalar string attribute (str or UTF-8 bytes)."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    text = _as_str(value)
    if text is None:
        raise InputError(f"{where}: attribute {key!r} must be a string, got {_describe(value)}")
    return text


def attr_int(attrs, key: str, where: str, default: Any = _MISSING) -> int:
    """A scalar integer attribute (not a bool, float or string)."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    if isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_):
        return int(value)
    raise InputError(f"{where}: attribute {key!r} must be an integer, got {_describe(value)}")


def attr_float(attrs, key: str, where: str, default: Any = _MISSING, positive: bool = False) -> float:
    """A finite scalar number attribute."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    if not isinstance(value, int | float | np.integer | np.floating) or isinstance(value, bool | np.bool_):
        raise InputError(f"{where}: attribute {key!r} must be a number, got {_describe(value)}")
    out = float(value)
    if not np.isfinite(out) or (positive and not out > 0):
        raise InputError(f"{where}: attribute {key!r} must be a finite{' positive' if positive else ''} "
                         f"number, got {out}")
    return out


def attr_json(attrs, key: str, where: str, default: Any = _MISSING, kind: type | None = None) -> Any:
    """A JSON-encoded string attribute, decoded (``kind``: the type the value must have)."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    text = attr_str(attrs, key, where)
    try:
        out = json.loads(text)
    except (json.JSONDecodeError, RecursionError) as exc:
        raise InputError(f"{where}: attribute {key!r} is not valid JSON ({_first(exc)})") from None
    if kind is not None and not isinstance(out, kind):
        raise InputError(f"{where}: attribute {key!r} must be a JSON {kind.__name__}, got {_describe(out)}")
    return out


def attr_strings(attrs, key: str, where: str, n: int) -> list[str]:
    """A 1-D array of ``n`` strings (absent → ``n`` empty strings)."""
    value = _attr(attrs, key, where, None)
    if value is None:
        return [""] * n
    arr = np.asarray(value)
    texts = [_as_str(v) for v in arr.ravel()] if arr.ndim == 1 else None
    if texts is None or any(t is None for t in texts) or len(texts) != n:
        raise InputError(f"{where}: attribute {key!r} must be {n} strings, got {_describe(value)}")
    return texts  # type: ignore[return-value]


def members(group, where: str) -> list[str]:
    """Names of the members of ``group`` (a damaged group index is an InputError)."""
    try:
        return list(group)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {group.name} cannot be listed ({_first(exc)})") from None


def has(group, name: str, where: str) -> bool:
    """``name in group``, with a damaged group an InputError."""
    try:
        return name in group
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {group.name}/{name} cannot be looked up ({_first(exc)})") from None


def _dataset_id(group, name: str, where: str):
    """The low-level ``DatasetID`` of ``name`` under ``group`` (InputError if absent or not
    a dataset)."""
    import h5py
    from h5py import h5d, h5o

    try:
        if "/" in name or name in (".", ""):  # a path: h5py's lookup walks it
            obj = group[name] if name in group else None
        else:  # one link: libhdf5 directly (h5py's ``in`` + ``[]`` cost 4× as much)
            raw = name.encode()
            obj = h5o.open(group.id, raw) if group.id.links.exists(raw) else None
    except (OSError, KeyError, RuntimeError, ValueError, TypeError, UnicodeEncodeError) as exc:
        raise InputError(f"{where}: {name} cannot be read ({_first(exc)})") from None
    if obj is None:
        raise InputError(f"{where}: {name} is missing")
    if isinstance(obj, h5d.DatasetID):
        return obj
    if isinstance(obj, h5py.Dataset):
        return obj.id
    kind = type(obj).__name__ if isinstance(obj, h5py.HLObject) else type(group[name]).__name__
    raise InputError(f"{where}: {name} must be a dataset, got a {kind}")


def dataset(group, name: str, where: str):
    """The ``h5py.Dataset`` ``name`` under ``group`` (InputError if absent or a group)."""
    import h5py

    return h5py.Dataset(_dataset_id(group, name, where))


def group_of(parent, name: str, where: str, required: bool = True):
    """The ``h5py.Group`` ``name`` under ``parent`` (None if absent and not ``required``)."""
    import h5py

    try:
        obj = parent.get(name)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {name} cannot be read ({_first(exc)})") from None
    if obj is None:
        if required:
            raise InputError(f"{where}: {name} is missing")
        return None
    if not isinstance(obj, h5py.Group):
        raise InputError(f"{where}: {name} must be a group, got a {type(obj).__name__}")
    return obj


def numeric(group, name: str, where: str, ndim: tuple[int, ...] = (1, 2), finite: bool = True,
            limit: float | None = None) -> np.ndarray:
    """A real numeric dataset as float64, of one of the dimensionalities ``ndim``.

    Checked before reading: the type (integers or floats, no strings, compounds,
    references) and the size (at most ``MAX_EXPANSION`` bytes per byte of file, against
    decompression bombs); after: finiteness (``finite``) and magnitude (``|v| <= limit``).
    """
    import h5py

    dsid = _dataset_id(group, name, where)  # no high-level Dataset: it costs as much as the read
    ds = functools.partial(h5py.Dataset, dsid)  # for messages: ds().name, ds().file
    try:
        dtype, shape = dsid.dtype, tuple(dsid.shape)
    except (OSError, RuntimeError, ValueError, TypeError) as exc:  # a damaged datatype or dataspace
        raise InputError(f"{where}: {ds().name} has an unreadable type or shape ({_first(exc)})") from None
    if dtype.kind not in "fiu":
        raise InputError(f"{where}: {ds().name} must be numeric, got dtype {dtype}")
    if len(shape) not in ndim:
        allowed = " or ".join(f"{d}-D" for d in ndim)
        raise InputError(f"{where}: {ds().name} must be {allowed}, got shape {shape}")
    nbytes = math.prod(shape) * 8
    if nbytes > (64 << 20) and nbytes > MAX_EXPANSION * os.path.getsize(ds().file.filename):
        raise InputError(f"{where}: {ds().name} claims shape {shape} ({nbytes} bytes), far more than the "
                         "file holds")
    from h5py import h5s

    try:  # libhdf5 converts to float64 while reading (h5py's ``ds[()]`` costs 4× as much)
        value = np.empty(shape, dtype=np.float64)
        if value.size:
            dsid.read(h5s.ALL, h5s.ALL, value)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {ds().name} cannot be read ({_first(exc)})") from None
    if finite and not np.isfinite(value).all():
        raise InputError(f"{where}: {ds().name} contains NaN or inf")
    if limit is not None and value.size and float(np.abs(value).max()) > limit:
        raise InputError(f"{where}: {ds().name} holds values beyond ±{limit:g} (max |v| = "
                         f"{np.abs(value).max():.3g}); no fit produces them and predictions would overflow")
    return value


def strings(group, name: str, where: str) -> list[str]:
    """A 1-D dataset of strings."""
    ds = dataset(group, name, where)
    label = f"{where}: {ds.name}"
    if ds.ndim != 1 or ds.dtype.kind not in "OSU":
        raise InputError(f"{label} must be a 1-D array of strings, got {ds.dtype} {ds.shape}")
    try:
        raw = ds[()]
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{label} cannot be read ({_first(exc)})") from None
    texts = [_as_str(v) for v in raw]
    if any(t is None for t in texts):
        raise InputError(f"{label} must hold strings")
    return texts  # type: ignore[return-value]
