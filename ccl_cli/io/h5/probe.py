"""Opening an HDF5 file as data, nothing more: :func:`open_hdf5`.

Every HDF5 file ccl reads (canonical demonstrations, models, foreign HDF5 and MATLAB v7.3
files) is opened here, which

1. refuses, before any value is read, external links, dangling soft links, datasets
   with external storage and virtual datasets (:func:`check_tree`): a file never makes
   ccl read another file;
2. protects against libhdf5 hanging or crashing on a damaged file. A file sealed by ccl
   (:mod:`ccl_cli.io.h5.seal`) whose content still matches its seal is opened directly;
   any other file (foreign, edited, damaged) is first parsed in a child process
   (:func:`probe`): every attribute, every string dataset and every dataset up to
   :data:`PROBE_BYTES` is read there, under a CPU-time limit (:data:`CPU_LIMIT`, via
   ``RLIMIT_CPU``; the hangs met in fuzzing are CPU-bound loops, and CPU time is robust on
   a loaded machine where wall time is not) with a wall-clock backstop (:data:`TIMEOUT`).
   A child over either limit, killed by a signal, or meeting any exception (a damaged
   attribute table, an unreadable dataset: it fails closed) means the file is refused:
   one line, and nothing of the file — not even an attribute by name — is read here.

``docs/readers.md`` records the fuzzing behind these limits.
"""

from __future__ import annotations

import faulthandler
import os
import re
import signal
import subprocess
import sys
import threading
import time
from pathlib import Path

from ccl_cli.errors import InputError
from ccl_cli.io.h5.access import error_text
from ccl_cli.io.h5.seal import sealed
from ccl_cli.io.limits import regular_file

#: CPU seconds a foreign file may take to be parsed in the child process, and the
#: wall-clock backstop
CPU_LIMIT = int(os.environ.get("CCL_HDF5_CPU_LIMIT", "2"))
TIMEOUT = float(os.environ.get("CCL_HDF5_TIMEOUT", "60"))
#: datasets up to this many bytes are read in the child (larger ones: metadata only)
PROBE_BYTES = 64 << 20
MAX_OBJECTS = 100_000
#: address space (bytes) the probe may add to what its process maps already: a damaged
#: file that makes libhdf5 allocate more (a string or attribute claiming gigabytes) is refused
PROBE_MEMORY = int(os.environ.get("CCL_HDF5_MEMORY_MB", "1024")) << 20


def _walk(f, where: str) -> None:
    """What the probe does: structure check, then read every attribute and every
    dataset that is small enough (values discarded)."""
    import h5py

    check_tree(f, where)
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


#: exit status of a probe child that met an exception (its message on its output)
REFUSED = 3
#: how a refusal says that the file did not even open (the parent words that message)
OPEN_FAILED = "open\t"


def _probe_child(path: str, cpu_limit: int = CPU_LIMIT) -> str | None:
    """Child side: parse the file under the CPU limit. Returns None when every part
    parsed, else the one-line refusal: any exception fails closed (the parent then reads
    nothing from the file, not even an attribute by name)."""
    import resource

    import h5py

    resource.setrlimit(resource.RLIMIT_CPU, (cpu_limit, cpu_limit + 1))
    _limit_memory()
    try:
        f = h5py.File(path, "r")
    except BaseException as exc:  # noqa: BLE001 - not HDF5, or a damaged superblock
        return f"{OPEN_FAILED}{error_text(exc)}"
    try:
        with f:
            _walk(f, path)
    except InputError as exc:
        return exc.message
    except MemoryError:
        return (f"{path}: parsing the file needs more than {PROBE_MEMORY >> 20} MiB of memory "
                "(damaged HDF5?); refused")
    except BaseException as exc:  # noqa: BLE001 - whatever libhdf5 or h5py raised: refused
        return f"{path}: libhdf5 failed parsing the file ({error_text(exc)}; damaged HDF5?); refused"
    return None


def _limit_memory() -> None:
    """Bound the probe's address space to what it maps now plus :data:`PROBE_MEMORY`
    (Linux: from /proc; elsewhere unbounded)."""
    import resource

    try:
        status = Path("/proc/self/status").read_text()
    except OSError:
        return
    found = re.search(r"^VmSize:\s+(\d+) kB", status, re.MULTILINE)
    if found is None:
        return
    limit = int(found.group(1)) * 1024 + PROBE_MEMORY
    _, hard = resource.getrlimit(resource.RLIMIT_AS)
    if hard != resource.RLIM_INFINITY:
        limit = min(limit, hard)
    resource.setrlimit(resource.RLIMIT_AS, (limit, hard))


def _probe_main(path: str, cpu_limit: str) -> None:
    """Entry of the fresh-interpreter probe: the refusal on stdout, exit :data:`REFUSED`."""
    refusal = _probe_child(path, int(cpu_limit))
    if refusal is not None:
        sys.stdout.write(refusal[:2000])
        sys.stdout.flush()
        os._exit(REFUSED)
    os._exit(0)


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


def probe(path: Path, timeout: float = TIMEOUT, cpu_limit: int = CPU_LIMIT, what: str = "file") -> None:
    """Parse ``path`` in a child process first; refuse it if libhdf5 hangs or crashes there.

    A fork of this process when it runs one thread (fast: h5py is already loaded);
    otherwise a fresh interpreter (forking a threaded process could deadlock the child).
    """
    import h5py  # noqa: F401 - loaded before the fork, so the child does not import it

    where = str(path)
    refusal = ""
    if hasattr(os, "fork") and threading.active_count() == 1:
        read_end, write_end = os.pipe()
        pid = os.fork()
        if pid == 0:  # child: never returns into the caller's code
            code = REFUSED
            try:
                os.close(read_end)
                signal.signal(signal.SIGINT, signal.SIG_IGN)  # the parent handles Ctrl-C
                faulthandler.disable()  # a crash here is reported by the parent, in one line
                found = _probe_child(where, cpu_limit)
                if found is None:
                    code = 0
                else:
                    os.write(write_end, found.encode("utf-8", "replace")[:2000])
            finally:
                os._exit(code)
        os.close(write_end)
        try:
            code = _wait(pid, timeout)
            if code == REFUSED:
                refusal = os.read(read_end, 4096).decode("utf-8", "replace")
        finally:
            os.close(read_end)
    else:
        cmd = [sys.executable, "-c", "import sys; from ccl_cli.io.h5.probe import _probe_main; "
               "_probe_main(sys.argv[1], sys.argv[2])", where, str(cpu_limit)]
        try:
            proc = subprocess.run(cmd, timeout=timeout, stdin=subprocess.DEVNULL, capture_output=True)
            code, refusal = proc.returncode, proc.stdout.decode("utf-8", "replace")
        except subprocess.TimeoutExpired:
            code = None
    if code is None or code == -signal.SIGXCPU:
        limit = f"{timeout:g} s" if code is None else f"{cpu_limit} s of CPU time"
        raise InputError(f"{where}: libhdf5 did not finish parsing the file within {limit} "
                         "(damaged HDF5?); refused")
    if code < 0:
        raise InputError(f"{where}: libhdf5 crashed parsing the file (signal {-code}; damaged HDF5?); "
                         "refused")
    if code != 0:  # an exception in the child (or an exit of its own): fail closed
        if refusal.startswith(OPEN_FAILED):
            raise InputError(f"{where}: cannot open as HDF5 {what} ({refusal[len(OPEN_FAILED):].strip()})")
        line = refusal.strip().splitlines()[0] if refusal.strip() else \
            f"{where}: libhdf5 failed parsing the file (exit {code}; damaged HDF5?); refused"
        raise InputError(line)


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
    if not path.exists():
        raise InputError(f"{where}: no such {what}")
    regular_file(path, f"the {what}")  # a FIFO or device would block libhdf5's open
    key = _identity(path)
    if key not in _PROBED and not sealed(path):
        # one probe per file version and process (a run opens a file twice)
        probe(path, TIMEOUT if timeout is None else timeout, what=what)
        _PROBED.add(key)
    try:
        f = h5py.File(path, "r")
    except (OSError, ValueError, RuntimeError) as exc:
        raise InputError(f"{where}: cannot open as HDF5 {what} ({error_text(exc)})") from None
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
    anywhere under ``f`` (an open ``h5py.File``). Reads metadata only, never a value: one
    libhdf5 visit of the link table collecting (name, link type), then one ``H5Oopen`` per
    hard link."""
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
        raise InputError(f"{where}: damaged HDF5 structure ({error_text(cause or exc)})") from None
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
        except InputError:  # said above (an InputError is a ValueError too)
            raise
        except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
            raise InputError(f"{where}: damaged HDF5 structure at /{name} ({error_text(exc)})") from None
