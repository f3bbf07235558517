"""Atomic outputs: write to a temporary sibling, rename into place on success.

* Nothing partial: a failure (including Ctrl-C, a full disk or a read-only folder)
  removes the temporary and leaves the destination as it was; I/O failures become one
  :class:`~ccl_cli.errors.InputError` line.
* Never lose data: ``force`` replaces an existing *folder* only if ccl wrote it (it holds
  the :data:`MARKER` file, or — folders of earlier versions — a ``run.json`` with
  ``command`` and ``versions``). Anything else is refused, untouched.
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
import tempfile
from collections.abc import Iterator
from pathlib import Path

from ccl_cli.errors import InputError
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


def written_by_ccl(path: Path) -> bool:
    """True for a folder ccl wrote (marker file, or a run.json of an earlier version)."""
    if (path / MARKER).is_file():
        return True
    try:
        run = json.loads((path / "run.json").read_text())
    except (OSError, UnicodeDecodeError, json.JSONDecodeError, RecursionError):
        return False
    return isinstance(run, dict) and "command" in run and "versions" in run


def check_replaceable(path: Path, force: bool) -> None:
    """A folder output: an existing one is replaced only with ``force`` and only if ccl
    wrote it."""
    path = Path(path)
    if not path.exists() and not path.is_symlink():
        return
    if not force:
        raise InputError(f"{path} exists; use --force to overwrite it")
    if path.is_symlink() or not path.is_dir():
        raise InputError(f"{path} exists and is not a folder ccl wrote; --force replaces only those "
                         "(remove it yourself or choose another output)")
    if not written_by_ccl(path):
        raise InputError(f"{path} exists and was not written by ccl (no {MARKER} or run.json in it); "
                         "--force replaces only folders ccl wrote (remove it yourself or choose another "
                         "output)")


_TEMP = re.compile(r"^\.(?P<name>.+)\.(?P<pid>\d+)\.[A-Za-z0-9_]+\.tmp$|^\.(?P<old>.+)\.old-(?P<opid>\d+)$")


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


def _failed(path: Path, exc: OSError) -> InputError:
    reason = exc.strerror or (str(exc).splitlines()[0] if str(exc) else type(exc).__name__)
    return InputError(f"{path}: cannot write the output ({reason}); nothing was written")


def _prefix(path: Path) -> str:
    return f".{path.name}.{os.getpid()}."


@contextlib.contextmanager
def atomic_path(path: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary path next to ``path``; on success it replaces ``path``.

    On any exception the temporary file is removed and ``path`` is untouched; an
    ``OSError`` (disk full, read-only folder, ...) becomes an :class:`InputError`.
    """
    path = Path(path)
    check_writable(path, force)
    tmp_path = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale(path)
        fd, tmp = tempfile.mkstemp(prefix=_prefix(path), suffix=".tmp", dir=path.parent)
        os.close(fd)
        tmp_path = Path(tmp)
        yield tmp_path
        os.chmod(tmp_path, 0o666 & ~_umask())
        os.replace(tmp_path, path)
    except OSError as exc:
        raise _failed(path, exc) from None
    finally:
        if tmp_path is not None:
            with contextlib.suppress(OSError):
                tmp_path.unlink()


@contextlib.contextmanager
def atomic_dir(path: str | Path, force: bool = False) -> Iterator[Path]:
    """Yield a temporary directory next to ``path``; on success it becomes ``path``
    (an existing one is replaced only with ``force``, and only if ccl wrote it).
    Interrupted → nothing left; an ``OSError`` becomes an :class:`InputError`."""
    path = Path(path)
    check_replaceable(path, force)
    tmp = None
    try:
        path.parent.mkdir(parents=True, exist_ok=True)
        clean_stale(path)
        tmp = Path(tempfile.mkdtemp(prefix=_prefix(path), suffix=".tmp", dir=path.parent))
        yield tmp
        from ccl_cli import __version__

        (tmp / MARKER).write_text(json.dumps({"written_by": "ccl", "version": __version__}) + "\n")
        os.chmod(tmp, 0o777 & ~_umask())
        if path.exists():
            check_replaceable(path, force)  # it may have appeared while we computed
            old = path.with_name(f".{path.name}.old-{os.getpid()}")
            os.replace(path, old)
            os.replace(tmp, path)
            shutil.rmtree(old, ignore_errors=True)
        else:
            os.replace(tmp, path)
        tmp = None
    except OSError as exc:
        raise _failed(path, exc) from None
    finally:
        if tmp is not None:
            shutil.rmtree(tmp, ignore_errors=True)
