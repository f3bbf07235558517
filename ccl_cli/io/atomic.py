"""Atomic outputs: write to a temporary sibling, rename into place on success.

* Nothing partial: a failure (including Ctrl-C, a full disk or a read-only folder)
  removes the temporary and leaves the destination as it was; I/O failures become one
  :class:`~ccl_cli.errors.InputError` line.
* Never lose data: ``force`` replaces an existing *folder* only if ccl marked it: it holds
  the :data:`MARKER` file, a regular file of ccl's own content (:func:`marked`). Anything
  else is refused, untouched — also a folder that merely holds a ``run.json`` like ccl's
  (any tool may write one; the refusal says how to remove an earlier ccl's output).
* Temporaries are named ``.<name>.<pid>.<random>.tmp``; those of processes that no longer
  run (a killed run) are removed the next time the same output is written.
* Outputs follow the umask (``mkstemp``/``mkdtemp`` would make them private).
"""

from __future__ import annotations

import contextlib
import json
import os
import re
import shutil
import stat
import tempfile
from collections.abc import Callable, Iterator
from dataclasses import dataclass
from pathlib import Path
from typing import Any

from ccl_cli.errors import InputError, OutputError
from ccl_cli.lifeline import pid_alive

#: file every output folder ccl writes holds (JSON: written_by, version)
MARKER = ".ccl-output"


def _umask() -> int:
    mask = os.umask(0o022)
    os.umask(mask)
    return mask


def check_writable(path: Path, force: bool) -> None:
    """A file output: an existing file is replaced only with ``force``; a folder never."""
    if path.is_dir():
        raise InputError(f"{path} is a folder; give a file name")
    if path.exists() and not force:
        raise InputError(f"{path} exists; use --force to overwrite it")


#: the largest marker read (it holds a few fields)
MARKER_BYTES = 4096


def marked(path: Path) -> bool:
    """True for a folder ccl marked: its :data:`MARKER` is a regular file (not a symlink) of at
    most :data:`MARKER_BYTES` holding ccl's JSON (``"written_by": "ccl"``)."""
    from ccl_cli.io.limits import open_regular

    marker = Path(path) / MARKER
    try:
        st = os.lstat(marker)
        if not stat.S_ISREG(st.st_mode) or st.st_size > MARKER_BYTES:
            return False
        with open_regular(marker, "the marker") as f:
            found = json.loads(f.read(MARKER_BYTES))
    except (OSError, InputError, ValueError, RecursionError):
        return False
    return isinstance(found, dict) and found.get("written_by") == "ccl"


def looks_like_an_output(path: Path) -> bool:
    """A folder holding a ``run.json`` with ``command`` and ``versions`` (as ccl's outputs
    did before the marker; any tool may write one)."""
    from ccl_cli.io.jsonsafe import loads

    try:
        run = loads((path / "run.json").read_bytes()[:1 << 20], str(path / "run.json"))
    except (OSError, InputError):
        return False
    return isinstance(run, dict) and "command" in run and "versions" in run


def not_marked(path: Path, action: str) -> InputError:
    """The refusal of a folder ccl did not mark (one line; a hint for one that looks like the
    output of an earlier ccl, written before the marker)."""
    if looks_like_an_output(path):
        return InputError(f"{path} exists and holds a run.json but no {MARKER} marker of ccl's: {action} "
                          "only folders ccl marked (an output of an earlier ccl, from before outputs were "
                          "marked? remove it yourself, or choose another output)")
    return InputError(f"{path} exists and was not written by ccl (no {MARKER} marker of ccl's in it); "
                      f"{action} only folders ccl marked (remove it yourself or choose another output)")


def check_replaceable(path: Path, force: bool) -> None:
    """A folder output: an existing one is replaced only with ``force`` and only if ccl
    marked it (:func:`marked`)."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        return
    if not force:
        raise InputError(f"{path} exists; use --force to overwrite it")
    if path.is_symlink() or not path.is_dir():
        raise InputError(f"{path} exists and is not a folder ccl wrote; --force replaces only those "
                         "(remove it yourself or choose another output)")
    if not marked(path):
        raise not_marked(path, "--force replaces")


_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.[A-Za-z0-9_]+\.tmp$|^\.(?P<old>.+)\.old-(?P<opid>\d+)$")


def is_temporary(name: str) -> bool:
    """True for the name of a temporary of an output being written (or of a killed run)."""
    return _TEMP.match(name) is not None


def clean_stale(path: Path, every: bool = False) -> int:
    """Remove temporaries of ``path`` (``every``: of anything in the folder ``path``) left
    by ccl processes that no longer run. Returns how many were removed."""
    n = 0
    folder = path if every else path.parent
    try:
        siblings = list(folder.iterdir())
    except OSError:
        return 0
    for p in siblings:
        m = _TEMP.match(p.name)
        if not m or (not every and (m.group("name") or m.group("old")) != path.name):
            continue
        if pid_alive(int(m.group("pid") or m.group("opid"))):
            continue
        if p.is_dir() and not p.is_symlink():
            shutil.rmtree(p, ignore_errors=True)
        else:
            with contextlib.suppress(OSError):
                p.unlink()
        n += 1
    return n


class WriteFailed(OutputError):
    """An output that could not be written, with the system's ``reason`` (e.g. "No space
    left on device"), so that an enclosing output can name itself instead."""

    def __init__(self, path: Path, reason: str) -> None:
        super().__init__(f"{path}: cannot write the output ({reason}); nothing was written")
        self.path = Path(path)
        self.reason = reason


def _failed(path: Path, exc: OSError | WriteFailed) -> WriteFailed:
    if isinstance(exc, WriteFailed):
        return WriteFailed(path, exc.reason)
    return WriteFailed(path, exc.strerror or (str(exc).splitlines()[0] if str(exc) else type(exc).__name__))


def _prefix(path: Path) -> str:
    return f".{path.name}.{os.getpid()}."


@dataclass(frozen=True)
class _Kind:
    """How one kind of output is staged: ``make(folder, prefix)`` creates the temporary,
    ``commit(tmp, path)`` puts it in place, ``discard(tmp)`` removes it."""

    make: Callable[[Path, str], Path]
    commit: Callable[[Path, Path], None]
    discard: Callable[[Path], None]


@contextlib.contextmanager
def _staged(path: Path, kind: _Kind) -> Iterator[Path]:
    """The one staging mechanism of every output: a temporary next to ``path`` (stale ones
    of dead processes removed first), yielded, committed on success and removed on any
    failure (an exception, Ctrl-C). An ``OSError`` anywhere — a full disk (ENOSPC), a
    file-size limit (EFBIG; ``ccl`` ignores SIGXFSZ so the limit is a write error), a
    read-only folder — becomes one :class:`InputError` line."""
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale(path)
        tmp = kind.make(path.parent, _prefix(path))
        yield tmp
        kind.commit(tmp, path)
        tmp = None
    except OSError as exc:
        raise _failed(path, exc) from None
    except WriteFailed as exc:  # a part inside this output failed: the output names itself
        if tmp is None or tmp not in exc.path.parents:
            raise
        raise _failed(path, exc) from None
    finally:
        if tmp is not None:
            kind.discard(tmp)


def _make_file(folder: Path, prefix: str) -> Path:
    fd, tmp = tempfile.mkstemp(prefix=prefix, suffix=".tmp", dir=folder)
    os.close(fd)
    return Path(tmp)


def _commit_file(tmp: Path, path: Path) -> None:
    os.chmod(tmp, 0o666 & ~_umask())
    os.replace(tmp, path)


def _discard_file(tmp: Path) -> None:
    with contextlib.suppress(OSError):
        tmp.unlink()


def _make_dir(folder: Path, prefix: str) -> Path:
    return Path(tempfile.mkdtemp(prefix=prefix, suffix=".tmp", dir=folder))


def _commit_dir(tmp: Path, path: Path, force: bool) -> None:
    """Mark the folder as ccl's, then swap it in (an existing one only if ccl wrote it)."""
    mark(tmp)
    os.chmod(tmp, 0o777 & ~_umask())
    if path.exists():
        check_replaceable(path, force)  # it may have appeared while we computed
        old = path.with_name(f".{path.name}.old-{os.getpid()}")
        os.replace(path, old)
        os.replace(tmp, path)
        shutil.rmtree(old, ignore_errors=True)
    else:
        os.replace(tmp, path)


def _discard_dir(tmp: Path) -> None:
    shutil.rmtree(tmp, ignore_errors=True)


FILE = _Kind(_make_file, _commit_file, _discard_file)


def mark(folder: Path, **extra: Any) -> None:
    """Write the :data:`MARKER` that says ccl wrote ``folder`` (``extra``: more JSON fields)."""
    from ccl_cli import __version__

    (folder / MARKER).write_text(json.dumps({"written_by": "ccl", "version": __version__, **extra}) + "\n")


@contextlib.contextmanager
def atomic_path(path: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it replaces ``path``.

    On any exception the temporary file is removed and ``path`` is untouched; an
    ``OSError`` (disk full, read-only folder, ...) becomes an :class:`InputError`.
    """
    path = Path(path)
    check_writable(path, force)
    with _staged(path, FILE) as tmp:
        yield tmp


@contextlib.contextmanager
def atomic_dir(path: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary directory next to ``path``; on success it becomes ``path``
    (an existing one is replaced only with ``force``, and only if ccl wrote it).
    Interrupted → nothing left; an ``OSError`` becomes an :class:`InputError`."""
    path = Path(path)
    check_replaceable(path, force)
    kind = _Kind(_make_dir, lambda tmp, dst: _commit_dir(tmp, dst, force), _discard_dir)
    with _staged(path, kind) as tmp:
        yield tmp


# -- folders written piece by piece (ccl batch) ----------------------------------------------------
def _created_here(path: Path) -> bool:
    """True when this process created ``path`` (:func:`claim_folder` recorded its pid)."""
    try:
        found = json.loads((path / MARKER).read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        return False
    return isinstance(found, dict) and found.get("created_by_pid") == os.getpid()


def claim_folder(path: str | Path, earlier: Callable[[Path], bool] | None = None) -> bool:
    """Make ``path`` a folder ccl may write into piece by piece (``ccl batch -o``): created
    here (and marked), or an empty folder (marked), or one ccl marked before (:func:`marked`).
    A user's folder with anything in it, or a file, is refused untouched: one
    :class:`InputError` line (with a hint when ``earlier(path)`` recognises what an earlier
    ccl wrote before the marker). Returns True when this call created the folder."""
    path = Path(path)
    try:
        if path.is_symlink() or (path.exists() and not path.is_dir()):
            raise InputError(f"{path} exists and is not a folder ccl made; choose another output")
        created = not path.exists()
        was_marked = not created and marked(path)
        if not created and not was_marked and any(path.iterdir()):
            hint = " (the batch folder of an earlier ccl, from before outputs were marked? remove it " \
                "yourself, or choose another output)" if earlier is not None and earlier(path) else \
                " (choose another output)"
            raise InputError(f"{path} holds files ccl did not write (no {MARKER} in it); ccl writes only "
                             f"into a new or empty folder or one it marked{hint}")
        path.mkdir(parents=True, exist_ok=True)
        if not was_marked:
            mark(path, **({"created_by_pid": os.getpid()} if created else {}))
    except OSError as exc:
        raise _failed(path, exc) from None
    return created


def release_folder(path: str | Path, fault: bool = False) -> None:
    """Undo :func:`claim_folder` where nothing was written: empty subfolders go, and the
    folder itself when only its marker is left in it (a folder holding any output keeps
    its marker, so a later run may resume in it). ``fault`` (an output could not be
    written): a folder this process created goes whole, as an atomic output would."""
    path = Path(path)
    if fault and _created_here(path):
        shutil.rmtree(path, ignore_errors=True)
        return
    for folder, _, _ in os.walk(path, topdown=False):
        if Path(folder) != path:
            with contextlib.suppress(OSError):
                os.rmdir(folder)  # only empty ones go
    with contextlib.suppress(OSError):
        if [p.name for p in path.iterdir()] == [MARKER]:
            (path / MARKER).unlink()
            path.rmdir()
