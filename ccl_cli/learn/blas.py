"""The number of threads of the BLAS behind NumPy and SciPy, set around small problems.

Small problems do not profit from BLAS threads, and on a machine whose cores are shared
they lose badly: a LAPACK call (e.g. ``eigh`` of a 200 × 200 normal matrix) makes
hundreds of threaded BLAS calls, each waiting for every thread, so one descheduled
thread stalls them all (docs/measurements.md, "BLAS threads"). Every learner's fit runs
single-threaded (its results must not depend on the count), and so does the rest of a run
(:data:`RUN_THREADS`, recorded in run.json): predictions, scores and diagnostics work in
row blocks whose products (8192 × p × K) are too small to share at any N.

The threads are set through threadpoolctl (OpenBLAS, MKL, BLIS, ...); where no BLAS can
be controlled nothing changes and :func:`threads` yields None.
"""

from __future__ import annotations

import contextlib
import contextvars
import os
import sys
from collections.abc import Iterator
from dataclasses import dataclass

#: BLAS threads of a run, at any size: its products are row blocks of at most a few thousand
#: rows by a few dozen columns, where a second thread costs more than it gives (RBF features of
#: 10⁶ rows on the 2 shared cores: 1.43 s CPU and 4.7 s wall with 2 threads, 0.51 and 1.8 with 1).
RUN_THREADS = 1
#: The variables that set the BLAS (and OpenMP) threads of a process started after them
#: (``ccl batch`` sets them to share the cores between its workers).
THREAD_VARS = ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS")


def affinity_cores() -> int:
    """The cores this process may run on: its CPU affinity (where there is no affinity API,
    e.g. macOS, ``os.process_cpu_count`` of Python 3.13, else all cores)."""
    try:
        return max(1, len(os.sched_getaffinity(0)))
    except AttributeError:
        return getattr(os, "process_cpu_count", os.cpu_count)() or 1


def _blas_pools() -> list[dict]:
    from threadpoolctl import threadpool_info

    return [p for p in threadpool_info() if p.get("user_api") == "blas"]


def controllable() -> bool:
    """True when the BLAS threads can be set at run time."""
    return bool(_blas_pools())


def current() -> int | None:
    """BLAS threads now (the first BLAS library's), or None when there is none to control."""
    pools = _blas_pools()
    return int(pools[0]["num_threads"]) if pools else None


@dataclass
class _Limit:
    """The limit an enclosing :func:`threads` block of this thread (or task) set: its count, the
    number of modules loaded when it last scanned the libraries, and the limits to undo."""

    n: int
    modules: int
    undo: contextlib.ExitStack


_IN_FORCE: contextvars.ContextVar[_Limit | None] = contextvars.ContextVar("ccl_blas_threads", default=None)


@contextlib.contextmanager
def threads(n: int | None) -> Iterator[int | None]:
    """Run the block with ``n`` BLAS threads (None: unchanged); yields the threads in force
    (None when the BLAS cannot be controlled). The previous counts are restored after.

    Inside a block that already set ``n`` nothing is scanned again (a search runs hundreds of
    fits, each in its own block) — unless a module was imported since, which may have loaded
    another BLAS: that one is then limited too, until the enclosing block ends."""
    if n is None:
        yield current()
        return
    from threadpoolctl import ThreadpoolController

    outer = _IN_FORCE.get()
    if outer is not None and outer.n == int(n):
        if outer.modules != len(sys.modules):
            pools = ThreadpoolController().select(user_api="blas")
            if pools:
                outer.undo.enter_context(pools.limit(limits=int(n)))
            outer.modules = len(sys.modules)
        yield n
        return
    pools = ThreadpoolController().select(user_api="blas")  # one scan of the loaded libraries
    if not pools:
        yield None
        return
    with contextlib.ExitStack() as undo:
        undo.enter_context(pools.limit(limits=int(n)))
        token = _IN_FORCE.set(_Limit(int(n), len(sys.modules), undo))
        try:
            yield n
        finally:
            _IN_FORCE.reset(token)


#: The commands whose every BLAS call runs at :data:`RUN_THREADS` (they learn through
#: ``ccl_cli.app.run.execute``): their NumPy may start its BLAS at that count.
RUN_COMMANDS = frozenset({"learn-a", "learn-v", "learn-pi", "run"})


def import_numpy_at_run_threads() -> bool:
    """Import NumPy with its BLAS started at :data:`RUN_THREADS` threads, for a command whose
    every product runs at that count (:data:`RUN_COMMANDS`): OpenBLAS otherwise starts a thread
    per core when it loads, only for the run to limit it to one (``import numpy`` on 2 cores:
    0.14 → 0.08 s CPU). True when it did; nothing changes when NumPy is loaded already or the
    user set the threads (:data:`THREAD_VARS`). The variables are removed again once NumPy is
    loaded, so the processes ccl starts later (a batch's workers) and the thread count
    :func:`ccl_cli.io.blockwise.cores` reads are as before."""
    if "numpy" in sys.modules or any(var in os.environ for var in THREAD_VARS):
        return False
    os.environ.update({var: str(RUN_THREADS) for var in THREAD_VARS})
    try:
        import numpy  # noqa: F401 - its BLAS reads the variables as it loads
    finally:
        for var in THREAD_VARS:
            os.environ.pop(var, None)
    return True
