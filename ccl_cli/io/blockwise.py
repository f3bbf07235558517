"""Passes over long recordings in blocks of samples, the blocks spread over the machine's cores.

A pass over positions (a stencil of neighbours at every sample) runs in blocks of
:data:`BLOCK_ROWS` samples, so that its temporaries are (BLOCK_ROWS, d) whatever the length
of the recording. NumPy releases the GIL inside its loops over large arrays, so the blocks
run on threads, one per core ccl may use (:func:`cores`). Each block writes only its own
slice of the output and reads none of another's: the result is the same bit for bit
whatever the number of threads.
"""

from __future__ import annotations

import os
from collections.abc import Callable

from ccl_cli.learn.blas import THREAD_VARS, affinity_cores

#: Samples per block (a block's temporaries: BLOCK_ROWS × d float64, for d ≤ 8 within a
#: core's L2 cache; the fault passes of 10⁶ 7-D samples: docs/measurements.md).
BLOCK_ROWS = 1 << 13
def blocks(start: int, stop: int, rows: int | None = None) -> list[tuple[int, int]]:
    """[s, e) blocks of at most ``rows`` (None: :data:`BLOCK_ROWS`) samples covering [start, stop)."""
    rows = rows or BLOCK_ROWS
    return [(s, min(s + rows, stop)) for s in range(start, stop, rows)]


def cores() -> int:
    """The cores this process may use (its CPU affinity), at most the thread count a batch
    gave each worker (:data:`~ccl_cli.learn.blas.THREAD_VARS`, the first one set)."""
    n = affinity_cores()
    for var in THREAD_VARS:
        value = os.environ.get(var, "")
        if value.isdigit() and int(value) > 0:
            return max(1, min(n, int(value)))
    return n


def each_block(work: Callable[[int, int], None], start: int, stop: int, rows: int | None = None) -> None:
    """Call ``work(s, e)`` on every block of [start, stop) (:func:`blocks`): on :func:`cores`
    threads when there is more than one block, each taking every so many blocks in one task
    (a task per block cost more than the threads gained at 8,192 rows). ``work`` writes its
    results into slices [s, e) of arrays made beforehand; an exception in any block is raised
    here."""
    spans = blocks(start, stop, rows)
    threads = min(cores(), len(spans))
    if threads <= 1:
        for s, e in spans:
            work(s, e)
        return
    from concurrent.futures import ThreadPoolExecutor

    def share(k: int) -> None:  # every threads-th block from the k-th: one task per thread
        for s, e in spans[k::threads]:
            work(s, e)

    with ThreadPoolExecutor(threads, thread_name_prefix="ccl-block") as pool:
        for future in [pool.submit(share, k) for k in range(threads)]:
            future.result()
