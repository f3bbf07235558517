"""Time blocks of demonstrations: window j of demonstration d holds its samples with
j·W ≤ t < (j + 1)·W (W the window length in s), or one window per demonstration — the windows
of :class:`~.windows.PerWindow` and the blocks of :class:`~.stretches.ConstraintInStretches`.

Shapes: groups (N,) demonstration ids, t (N,) s; a table (S, 2) [demonstration id, j].
"""

from __future__ import annotations

import numpy as np

from ccl_cli.errors import InputError


def window_index(groups: np.ndarray | None, t: np.ndarray | None, window: float | None,
                 n: int) -> tuple[np.ndarray, np.ndarray]:
    """(segment id per sample (n,), table (S, 2) of [demonstration id, window index j]) for
    windows of ``window`` s fixed in time (j = ⌊t / window⌋), or one per demonstration when
    ``window`` is None. Segment ids follow the table's rows (sorted by demonstration, then j)."""
    demo = np.zeros(n, np.int64) if groups is None else np.asarray(groups).astype(np.int64)
    if window is None:
        j = np.zeros(n, np.int64)
    else:
        if t is None:
            raise InputError("a per-window constraint needs the sample times t")
        j = np.floor(np.asarray(t, float) / window).astype(np.int64)
    table, seg = np.unique(np.stack([demo, j], 1), axis=0, return_inverse=True)
    return seg.ravel(), table

def nearest_window(table: np.ndarray, window: float | None, n: int, groups: np.ndarray | None,
                   t: np.ndarray | None, what: str = "per-window") -> np.ndarray:
    """Index (n,) into ``table`` (S, 2) [demonstration id, window index j] of windows of
    ``window`` s (None: one per demonstration) of each sample of demonstrations ``groups`` (n,)
    at times ``t`` (n,): its own window, else the nearest one of its demonstration in the table
    (InputError for a demonstration not in it)."""
    demos = table[:, 0]
    if groups is None:
        if len(np.unique(demos)) > 1:
            raise InputError(f"a {what} constraint model needs the demonstration ids")
        groups = np.full(n, demos[0])
    groups = np.asarray(groups).astype(np.int64)
    if window is not None and t is None:
        raise InputError(f"a {what} constraint model needs the sample times t")
    j = np.zeros(n) if window is None else np.asarray(t, float) / window - 0.5
    out = np.empty(n, np.int64)
    for d in np.unique(groups):  # a loop over demonstrations, not samples
        mine = np.flatnonzero(demos == d)
        if not len(mine):
            raise InputError(f"demonstration {int(d)} was not seen when fitting this {what} model; "
                             "fit it on the new data")
        m = groups == d
        centres = table[mine, 1].astype(float)
        pos = np.clip(np.searchsorted(centres, j[m]), 1, max(len(mine) - 1, 1))
        lo = mine[pos - 1]
        hi = mine[np.minimum(pos, len(mine) - 1)]
        nearer_hi = np.abs(table[hi, 1] - j[m]) < np.abs(table[lo, 1] - j[m])
        out[m] = np.where(nearer_hi, hi, lo)
    return out
