"""The number of threads of the BLAS behind NumPy and SciPy, set at run time.

Small problems do not profit from BLAS threads, and on a machine whose cores are shared
they lose badly: a LAPACK call (e.g. ``eigh`` of a 200 × 200 normal matrix) makes
hundreds of threaded BLAS calls, each waiting for every thread, so one descheduled
thread stalls them all (measured on a 2-core VM with a busy neighbour: 200 × 200 ``eigh``
3 ms single-threaded, up to 210 ms with 2 threads; a 100-centre pi-coupled fit 0.07 s
against 0.4–1.5 s). :class:`Pipeline` therefore runs a stage on a small training set
single-threaded (:data:`SMALL_SAMPLES`) and records the choice in run.json.

The OpenBLAS builds shipped in NumPy and SciPy wheels (``scipy_openblas``, 64- and
32-bit integer interfaces) are driven through their ``*_set_num_threads`` entry points,
as threadpoolctl does; with any other BLAS nothing is changed and :func:`threads` says so.
"""

from __future__ import annotations

import contextlib
import ctypes
import functools
import glob
import os
from collections.abc import Iterator

#: Stages on fewer training samples than this run with one BLAS thread.
SMALL_SAMPLES = 20_000


@functools.cache
def _candidates() -> tuple[str, ...]:
    """Paths of the OpenBLAS libraries vendored in the NumPy and SciPy wheels in use."""
    import importlib.util

    paths: list[str] = []
    for package in ("numpy", "scipy"):
        spec = importlib.util.find_spec(package)
        if spec is None or not spec.origin:
            continue
        here = os.path.dirname(spec.origin)
        paths += sorted(glob.glob(os.path.join(here + ".libs", "lib*openblas*.so*")))  # auditwheel (Linux)
        paths += sorted(glob.glob(os.path.join(here, ".dylibs", "lib*openblas*.dylib")))  # delocate (macOS)
    return tuple(paths)


_LOADED: dict[str, tuple[ctypes.CDLL, str] | None] = {}


def _libraries() -> list[tuple[ctypes.CDLL, str]]:
    """(library, entry-point tag) of every candidate OpenBLAS already loaded by NumPy or
    SciPy (one not loaded yet is left alone: loading it would start its threads)."""
    out = []
    noload = getattr(os, "RTLD_NOLOAD", None)
    for path in _candidates() if noload is not None else ():
        if path not in _LOADED:
            try:
                lib = ctypes.CDLL(path, mode=noload | os.RTLD_LAZY)
            except OSError:  # not loaded (yet)
                continue
            _LOADED[path] = None
            for prefix, suffix in (("scipy_openblas", "64_"), ("scipy_openblas", ""), ("openblas", "64_"),
                                   ("openblas", "")):
                if hasattr(lib, f"{prefix}_get_num_threads{suffix}") and \
                        hasattr(lib, f"{prefix}_set_num_threads{suffix}"):
                    _LOADED[path] = (lib, f"{prefix}|{suffix}")
                    break
        if _LOADED[path] is not None:
            out.append(_LOADED[path])
    return out


def _get(lib: ctypes.CDLL, tag: str) -> int:
    prefix, suffix = tag.split("|")
    return int(getattr(lib, f"{prefix}_get_num_threads{suffix}")())


def _set(lib: ctypes.CDLL, tag: str, n: int) -> None:
    prefix, suffix = tag.split("|")
    getattr(lib, f"{prefix}_set_num_threads{suffix}")(int(n))


def controllable() -> bool:
    """True when the BLAS threads can be set at run time (OpenBLAS from the wheels)."""
    return bool(_libraries())


def current() -> int | None:
    """BLAS threads now (the first controllable library's), or None when unknown."""
    libs = _libraries()
    return _get(*libs[0]) if libs else None


@contextlib.contextmanager
def threads(n: int | None) -> Iterator[int | None]:
    """Run the block with ``n`` BLAS threads (None: unchanged); yields the threads in force
    (None when the BLAS cannot be controlled). The previous counts are restored after."""
    libs = _libraries()
    if n is None or not libs:
        yield current() if n is None else None
        return
    before = [_get(lib, tag) for lib, tag in libs]
    try:
        for lib, tag in libs:
            _set(lib, tag, n)
        yield n
    finally:
        for (lib, tag), b in zip(libs, before, strict=True):
            _set(lib, tag, b)


def stage_threads(n_samples: int) -> int | None:
    """BLAS threads for a stage fitted on ``n_samples`` samples: 1 below
    :data:`SMALL_SAMPLES`, else None (the library's own count, e.g. one per core)."""
    return 1 if n_samples < SMALL_SAMPLES else None
