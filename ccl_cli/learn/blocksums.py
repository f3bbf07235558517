"""Sums over blocks of rows — the sufficient statistics of a fit, e.g. a policy's normal equations
M = Σ_blocks βᵀβ, r = Σ_blocks βᵀu (ALGORITHMS.md §4) — computed in this process or on a
dask.distributed cluster, by the same function.

:func:`block_sums` applies ``fn`` to the arrays of each block of rows (``take(s, e)``) and sums
what it returns, in block order. In this process: one block after another, as a left fold (the
sums of before, bit for bit). Inside :func:`on_cluster` the blocks go to the cluster's workers,
:data:`TASK_BLOCKS` consecutive blocks a task with their rows: each task folds its blocks with one
BLAS thread and sends back its partial sums (arrays of the statistics' size, e.g. (K q, K q)),
which are added here in task order — the same grouping whatever the load or the number of
workers. The result differs from this process's by rounding only (the sums are grouped by task,
and the workers' last bits are not always this process's: from one run to the next too), which
an iterative fit carries into a slightly different path. The rows travel once, with their task;
what comes back does not grow with N.

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


def task_groups(n: int, rows: int) -> list[list[tuple[int, int]]]:
    """The blocks of :func:`spans` in consecutive groups of :data:`TASK_BLOCKS`: one cluster task each."""
    blocks = spans(n, rows)
    return [blocks[i:i + TASK_BLOCKS] for i in range(0, len(blocks), TASK_BLOCKS)]


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
    order — here, or on the cluster of :func:`on_cluster` (:func:`worth_sending`); None when n = 0."""
    if not worth_sending(n, rows):
        return fold(fn, (take(s, e) for s, e in spans(n, rows)))  # each block taken as it is summed
    client, groups = _CLIENT.get(), task_groups(n, rows)
    parts: list[Any] = []
    try:
        for w in range(0, len(groups), WAVE):  # a wave of tasks at a time, gathered in order
            parts += client.gather([client.submit(_task, fn, [take(s, e) for s, e in group], pure=False)
                                    for group in groups[w:w + WAVE]])
    except Exception as exc:  # noqa: BLE001 - a lost cluster (or a task it could not run) is one line
        raise _lost(exc) from None
    return fold(lambda *p: p, [p for p in parts if p is not None])


class Held:
    """The rows of a fit's blocks held by the cluster's workers — sent once, read on every pass of
    an iterative fit — as one future per task of :data:`TASK_BLOCKS` blocks (``take(s, e)`` of
    each block), or what :meth:`map` computed of them there. Only inside :func:`on_cluster`.
    (A sum read once, :func:`block_sums`, sends each task's rows with the task instead: no data
    left on the workers, no round trip to scatter them.)"""

    def __init__(self, futures: list[Any], client: Any) -> None:
        self.futures, self.client = futures, client

    @classmethod
    def send(cls, take: Callable[[int, int], tuple[np.ndarray, ...]], n: int, rows: int) -> Held:
        client = _CLIENT.get()
        try:
            futures = [client.scatter([[take(s, e) for s, e in group]], hash=False)[0]  # keys of their own
                       for group in task_groups(n, rows)]
        except Exception as exc:  # noqa: BLE001 - one line, as block_sums
            raise _lost(exc) from None
        return cls(futures, client)

    def map(self, fn: Callable[..., tuple[np.ndarray, ...]], *args: Any) -> Held:
        """``fn(*args, *block)`` of every block, computed and kept where the block is."""
        return Held([self.client.submit(_map_task, fn, args, f, pure=False) for f in self.futures],
                    self.client)

    def sums(self, fn: Callable[..., tuple[np.ndarray, ...]], *args: Any, beside: tuple[Held, ...] = ()
             ) -> tuple[np.ndarray, ...] | None:
        """Σ over the blocks of ``fn(*args, *block, *its blocks of beside)``, in block order
        (:func:`block_sums`'s grouping)."""
        try:
            parts = self.client.gather([
                self.client.submit(_sum_task, fn, args, f, *(h.futures[i] for h in beside), pure=False)
                for i, f in enumerate(self.futures)])
        except Exception as exc:  # noqa: BLE001 - one line, as block_sums
            raise _lost(exc) from None
        return fold(lambda *p: p, [p for p in parts if p is not None])


def worth_sending(n: int, rows: int) -> bool:
    """Whether the block sums of n rows in blocks of ``rows`` go to the cluster: inside
    :func:`on_cluster`, for more rows than one task computes (a search's fits on its bounded
    subsample, and any fit of fewer rows, are computed here: one task gains nothing)."""
    return _CLIENT.get() is not None and n > TASK_BLOCKS * rows


def _map_task(fn: Callable[..., tuple[np.ndarray, ...]], args: tuple, group: list[tuple[np.ndarray, ...]]
              ) -> list[tuple[np.ndarray, ...]]:
    from ccl_cli.learn import blas

    with blas.threads(1):
        return [tuple(fn(*args, *block)) for block in group]


def _sum_task(fn: Callable[..., tuple[np.ndarray, ...]], args: tuple, *groups: list[tuple[np.ndarray, ...]]
              ) -> tuple[np.ndarray, ...] | None:
    return _task(lambda *block: fn(*args, *block), [sum(blocks, ()) for blocks in zip(*groups, strict=True)])


def _lost(exc: Exception) -> Exception:
    from ccl_cli.errors import LearningError

    first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
    return LearningError(f"the Dask cluster could not compute the block sums of a fit ({first})")
