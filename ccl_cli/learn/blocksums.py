"""Sums over blocks of rows — the sufficient statistics of a fit, e.g. a policy's normal equations
M = Σ_blocks βᵀβ, r = Σ_blocks βᵀu (ALGORITHMS.md §4) — computed in this process or on a
dask.distributed cluster, by the same function.

:func:`block_sums` applies ``fn`` to the arrays of each block of rows (``take(s, e)``) and sums
what it returns, in block order. In this process: one block after another, as a left fold (the
sums of before, bit for bit). Inside :func:`on_cluster` the blocks go to the cluster's workers,
:data:`TASK_BLOCKS` consecutive blocks a task with their rows: each task folds its blocks with one
BLAS thread and sends back its partial sums (arrays of the statistics' size, e.g. (K q, K q)),
which are added here in task order — the same grouping whatever the load or the number of
workers, so the same result on every run (it differs from this process's by rounding only: the
sums are grouped by task). The rows travel once, with their task; what comes back does not grow
with N.

Shapes: ``take(s, e)`` returns a tuple of arrays of rows [s, e); ``fn(*arrays)`` returns a tuple
of arrays of fixed shapes.
"""

from __future__ import annotations

import contextlib
import contextvars
from collections.abc import Callable, Iterable, Iterator
from typing import Any

import numpy as np

#: Consecutive blocks of rows computed by one task on a cluster (with 8192-row blocks, 131,072
#: rows a task: a 10⁷-sample fit is 77 tasks, not 1,221).
TASK_BLOCKS = 16
#: Tasks sent at once (the rows of at most this many tasks are copied and in flight).
WAVE = 32

_CLIENT: contextvars.ContextVar[Any] = contextvars.ContextVar("ccl_block_sums_client", default=None)


@contextlib.contextmanager
def on_cluster(client: Any) -> Iterator[None]:
    """Compute the block sums of the fits in this block on the dask.distributed ``client``'s
    cluster (None: in this process)."""
    token = _CLIENT.set(client)
    try:
        yield
    finally:
        _CLIENT.reset(token)


def spans(n: int, rows: int) -> list[tuple[int, int]]:
    """[s, e) blocks of at most ``rows`` rows covering 0..n."""
    return [(s, min(s + rows, n)) for s in range(0, n, rows)]


def fold(fn: Callable[..., tuple[np.ndarray, ...]], blocks: Iterable[tuple[np.ndarray, ...]]
         ) -> tuple[np.ndarray, ...] | None:
    """The sum of ``fn`` over ``blocks`` (each a tuple of its arrays), left to right; None for none."""
    total: list[np.ndarray] | None = None
    for arrays in blocks:
        part = fn(*arrays)
        if total is None:
            total = [np.array(p, dtype=float, copy=True) for p in part]
        else:
            for t, p in zip(total, part, strict=True):
                t += p
    return None if total is None else tuple(total)


def _task(fn: Callable[..., tuple[np.ndarray, ...]], blocks: list[tuple[np.ndarray, ...]]
          ) -> tuple[np.ndarray, ...] | None:
    """One cluster task: its blocks folded with one BLAS thread (as every fit here runs)."""
    from ccl_cli.learn import blas

    with blas.threads(1):
        return fold(fn, blocks)


def block_sums(fn: Callable[..., tuple[np.ndarray, ...]], take: Callable[[int, int], tuple[np.ndarray, ...]],
               n: int, rows: int) -> tuple[np.ndarray, ...] | None:
    """Σ over the blocks [s, e) of ``rows`` rows covering 0..n of ``fn(*take(s, e))``, in block
    order — here, or on the cluster of :func:`on_cluster`; None when n = 0."""
    blocks = spans(n, rows)
    client = _CLIENT.get()
    if client is None:
        return fold(fn, (take(s, e) for s, e in blocks))  # each block taken as it is summed
    groups = [blocks[i:i + TASK_BLOCKS] for i in range(0, len(blocks), TASK_BLOCKS)]
    parts: list[Any] = []
    try:
        for w in range(0, len(groups), WAVE):  # a wave of tasks at a time, gathered in order
            parts += client.gather([client.submit(_task, fn, [take(s, e) for s, e in group], pure=False)
                                    for group in groups[w:w + WAVE]])
    except Exception as exc:  # noqa: BLE001 - a lost cluster (or a task it could not run) is one line
        from ccl_cli.errors import LearningError

        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise LearningError(f"the Dask cluster could not compute the block sums of a fit ({first})") from None
    return fold(lambda *p: p, [p for p in parts if p is not None])
