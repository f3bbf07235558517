"""Input paths: globs to files, and content digests for provenance and batch keys.

Every caller of :func:`expand_files` then asks for the files' digests (a run's provenance,
a batch job's content key), so expanding starts them on a background thread: the digest
reads the file while the reader decodes it, and :func:`file_hash` waits for it.
"""

from __future__ import annotations

import functools
import glob
import hashlib
import os
import threading
from concurrent.futures import Future
from pathlib import Path

from ccl_cli.errors import InputError
from ccl_cli.io.limits import regular_file


def refuse_configs(files: list[Path] | list[str] | None) -> None:
    """Refuse a YAML file given as a recording (other than a ROS 2 bag's metadata.yaml): it is
    a config, passed with -c/--config."""
    for f in files or []:
        if Path(f).suffix.lower() in (".yaml", ".yml") and Path(f).name != "metadata.yaml":
            raise InputError(f"{f}: a YAML file is a config, not a recording: pass it with -c/--config "
                             "(or to ccl run), and the recordings as the data")


def expand_files(files: list[str] | str, base: Path | None = None) -> list[Path]:
    """Paths and globs → existing paths, in the order given (globs sorted)."""
    if isinstance(files, str | Path):
        files = [str(files)]
    if not isinstance(files, list | tuple) or not all(isinstance(f, str | Path) for f in files):
        raise InputError(f"files must be a path or a list of paths, got {files!r}"[:200])
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
    _hash_in_background(out)
    return out


Key = tuple[tuple[str, int, int], ...]
#: digests started by :func:`_hash_in_background`: key → (the process that started it, its result)
_started: dict[Key, tuple[int, Future]] = {}


def _key(path: Path) -> Key:
    """Every file of ``path`` (a file, or a bag directory's files in name order) with its
    size and modification time."""
    if not path.is_dir():
        regular_file(path)  # a FIFO would block the read
    paths = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    stats = [(p, p.stat()) for p in paths]
    return tuple((str(p.resolve()), st.st_size, st.st_mtime_ns) for p, st in stats)


def _hash_in_background(paths: list[Path]) -> None:
    """Start the digests of ``paths`` on one daemon thread (hashlib and file reads release
    the GIL); a path that cannot be keyed is left to :func:`file_hash` to refuse."""
    keys = []
    for path in paths:
        try:
            key = _key(Path(path))
        except (InputError, OSError):
            continue
        if key not in _started:
            _started[key] = (os.getpid(), Future())
            keys.append(key)
    if keys:
        threading.Thread(target=_run, args=(keys,), daemon=True, name="ccl-sha256").start()


def _run(keys: list[Key]) -> None:
    for key in keys:
        future = _started[key][1]
        try:
            future.set_result(_sha256_of(key))
        except BaseException as exc:  # handed to the caller of file_hash
            future.set_exception(exc)


def file_hash(path: Path) -> str:
    """sha256 of a file, or of a bag directory's files in name order.

    Digests are remembered for the process, keyed on every file's path, size and
    modification time, so an unchanged input is read once however many callers ask
    (a batch job's content key, then the run's provenance); one started by
    :func:`expand_files` is waited for (in a forked child it is computed anew).
    """
    key = _key(Path(path))
    started = _started.get(key)
    if started is not None and started[0] == os.getpid():
        return started[1].result()
    return _sha256_of(key)


@functools.lru_cache(maxsize=1024)
def _sha256_of(key: Key) -> str:
    h = hashlib.sha256()
    block = bytearray(1 << 20)
    view = memoryview(block)
    for name, _, _ in key:
        with open(name, "rb", buffering=0) as f:
            while size := f.readinto(block):
                h.update(view[:size])
    return h.hexdigest()
