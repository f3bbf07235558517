"""Input paths: globs to files, and content digests for provenance and batch keys."""

from __future__ import annotations

import functools
import glob
import hashlib
from pathlib import Path

from ccl_cli.errors import InputError
from ccl_cli.io.limits import regular_file


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
    return out


def file_hash(path: Path) -> str:
    """sha256 of a file, or of a bag directory's files in name order.

    Digests are remembered for the process, keyed on every file's path, size and
    modification time, so an unchanged input is read once however many callers ask
    (a batch job's content key, then the run's provenance).
    """
    path = Path(path)
    if not path.is_dir():
        regular_file(path)  # a FIFO would block the read
    paths = sorted(p for p in path.rglob("*") if p.is_file()) if path.is_dir() else [path]
    stats = [(p, p.stat()) for p in paths]
    return _sha256_of(tuple((str(p.resolve()), st.st_size, st.st_mtime_ns) for p, st in stats))


@functools.lru_cache(maxsize=1024)
def _sha256_of(key: tuple[tuple[str, int, int], ...]) -> str:
    h = hashlib.sha256()
    for name, _, _ in key:
        with open(name, "rb") as f:
            for block in iter(lambda: f.read(1 << 20), b""):
                h.update(block)
    return h.hexdigest()
