"""Input paths: files, globs and folders to recordings, and content digests for provenance
and batch keys.

Every command that reads recordings takes them alike: a path, a glob, or a folder that is
not a ROS 2 bag (it stands for the recordings in it). Every caller of :func:`expand_files`
then asks for the files' digests (a run's provenance, a batch job's content key), so
expanding starts them on a background thread: the digest reads the file while the reader
decodes it, and :func:`file_hash` waits for it.
"""

from __future__ import annotations

import functools
import glob
import hashlib
import logging
import os
import threading
from concurrent.futures import Future
from pathlib import Path

from ccl_cli.errors import InputError
from ccl_cli.io.limits import regular_file
from ccl_cli.io.sniff import is_bag, is_hdf5, is_mat, is_mcap, is_text, read_head

log = logging.getLogger("ccl")
#: the text files of a folder read as recordings (tables); other text (notes, configs) is not
TABLE_SUFFIXES = (".csv", ".tsv", ".txt", ".dat", ".log", ".asc")


def refuse_configs(files: list[Path] | list[str] | None) -> None:
    """Refuse a YAML file given as a recording (other than a ROS 2 bag's metadata.yaml): it is
    a config, passed with -c/--config."""
    for f in files or []:
        if Path(f).suffix.lower() in (".yaml", ".yml") and Path(f).name != "metadata.yaml":
            raise InputError(f"{f}: a YAML file is a config, not a recording: pass it with -c/--config "
                             "(or to ccl run), and the recordings as the data")


def expand_files(files: list[str] | str, base: Path | None = None, digests: bool = True) -> list[Path]:
    """Paths, globs and folders → existing recordings, in the order given (globs and a folder's
    recordings in name order, :func:`folder_recordings`). ``digests``: start their sha256 on a
    background thread (:func:`file_hash` waits for it)."""
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
            out += folder_recordings(p) if p.is_dir() and not is_bag(p, b"") else [p]
    if not out:
        raise InputError("no input files")
    if digests:
        _hash_in_background(out)
    return out


def folder_recordings(folder: Path) -> list[Path]:
    """The recordings in ``folder`` (not a ROS 2 bag itself), in name order: its ROS 2 bag
    folders, its files in a recording format their first bytes show (ROS 1 bag, MCAP, .mat,
    HDF5) and its text tables (:data:`TABLE_SUFFIXES`). Hidden entries, other folders and other
    files (notes, configs, pictures) are left out, said on the log; none left is an InputError."""
    try:
        entries = sorted(p for p in folder.iterdir() if not p.name.startswith("."))
    except OSError as exc:
        raise InputError(f"{folder}: {exc.strerror or type(exc).__name__}") from None
    found, left = [], []
    for p in entries:
        (found if _is_recording(p) else left).append(p)
    if not found:
        raise InputError(f"{folder}: a folder with no recording in it (no ROS 2 bag folder, ROS 1 bag, "
                         f"MCAP, .mat, HDF5 or {'/'.join(TABLE_SUFFIXES)} table"
                         + (f"; it holds {_listed(left)}" if left else "") + ")")
    if left:
        log.info("%s: %d recording(s); left out %s (not recordings)", folder, len(found), _listed(left))
    return found


def _listed(paths: list[Path], limit: int = 5) -> str:
    """The first ``limit`` folder entries by name (a folder's with a slash), and how many more."""
    names = ", ".join(p.name + ("/" if p.is_dir() else "") for p in paths[:limit])
    return names + (f" and {len(paths) - limit} more" if len(paths) > limit else "")


def _is_recording(path: Path) -> bool:
    """A ROS 2 bag folder, or a regular file in a recording format (its first bytes; a text
    file by its suffix too)."""
    if path.is_dir():
        return is_bag(path, b"")
    if not path.is_file():
        return False
    try:
        head = read_head(path)
    except InputError:
        return False
    if any(test(path, head) for test in (is_bag, is_mcap, is_mat, is_hdf5)):
        return True
    return bool(head) and path.suffix.lower() in TABLE_SUFFIXES and is_text(path, head)


#: Why a recording given twice is refused, for a dataset
TWICE = "a recording given twice would count its demonstrations twice (and could be trained and tested on)"


def given_once(paths: list[Path], digests: list[str] | None = None, why: str = TWICE) -> None:
    """Refuse a recording given twice — the same file (by its resolved path; a glob and a name
    can both reach it) or, with ``digests`` (sha256 of each), the same content under two names:
    its demonstrations would count twice, and a split could train and test on the same samples
    (``why``: what it would do instead, said in the message)."""
    seen: dict[object, Path] = {}
    for i, p in enumerate(paths):
        key = p.resolve() if digests is None else digests[i]
        if key in seen:
            what = (f"{p} is given twice" if str(p) == str(seen[key]) else
                    f"{seen[key]} and {p} are the same file" if digests is None else
                    f"{seen[key]} and {p} have the same content (sha256 {key[:12]}…)")
            raise InputError(f"{what}: {why}; give each once")
        seen[key] = p


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
