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
    pairs = np.stack([demo, j], 1)
    step = np.diff(demo)
    if np.all((step > 0) | ((step == 0) & (np.diff(j) >= 0))):  # in order already: no sort
        new = np.r_[True, (step != 0) | (np.diff(j) != 0)] if n else np.zeros(0, bool)
        return np.cumsum(new) - 1, pairs[new]
    table, seg = np.unique(pairs, axis=0, return_inverse=True)
    return seg.ravel(), table


def window_ends(table: np.ndarray) -> np.ndarray:
    """The end (exclusive, in windows) of each row of a table (S, 2) [demonstration id, j] — j + 1
    — or (S, 3) [demonstration id, first window, end window)."""
    return table[:, 2] if table.shape[1] == 3 else table[:, 1] + 1


def nearest_window(table: np.ndarray, window: float | None, n: int, groups: np.ndarray | None,
                   t: np.ndarray | None, what: str = "per-window") -> np.ndarray:
    """Index (n,) into ``table`` of the window of each sample of demonstrations ``groups`` (n,)
    at times ``t`` (n,). ``table`` is (S, 2) [demonstration id, window index j] of windows of
    ``window`` s (None: one per demonstration), or (S, 3) [demonstration id, first window, end
    window) of runs of consecutive windows (segments), sorted by demonstration, then time. A
    sample takes the row that holds its window j = ⌊t / window⌋, else the nearest row of its
    demonstration, counted in windows (InputError for a demonstration not in the table)."""
    demos = table[:, 0]
    first = table[:, 1]
    end = window_ends(table)
    if groups is None:
        if len(np.unique(demos)) > 1:
            raise InputError(f"a {what} constraint model needs the demonstration ids")
        groups = np.full(n, demos[0])
    groups = np.asarray(groups).astype(np.int64)
    if window is not None and t is None:
        raise InputError(f"a {what} constraint model needs the sample times t")
    j = np.zeros(n, np.int64) if window is None else np.floor(np.asarray(t, float) / window).astype(np.int64)
    order = np.argsort(demos, kind="stable")  # the table's rows by demonstration (sorted already)
    ids, start = np.unique(demos[order], return_index=True)
    stop = np.r_[start[1:], len(order)]
    rank = np.minimum(np.searchsorted(ids, groups), len(ids) - 1)
    missing = ids[rank] != groups
    if missing.any():
        raise InputError(f"demonstration {int(groups[missing].min())} was not seen when fitting this {what} "
                         "model; fit it on the new data")
    first, end, row_demo = first[order], end[order], np.repeat(np.arange(len(ids)), stop - start)
    # one search for every sample: keys (demonstration, window) in one increasing sequence; the
    # windows enter by their rank among all the values, so the keys never overflow
    values = np.unique(np.r_[end, j])
    span = len(values) + 1
    after = np.searchsorted(row_demo * span + np.searchsorted(values, end),
                            rank * span + np.searchsorted(values, j), side="right")  # first end > j
    after = np.minimum(after, stop[rank] - 1)
    before = np.maximum(after - 1, start[rank])
    to_after = np.maximum(first[after] - j, 0)  # 0 inside the row
    to_before = np.maximum(j - (end[before] - 1), 0)
    return order[np.where(to_after <= to_before, after, before)]
