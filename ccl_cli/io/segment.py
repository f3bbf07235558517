"""Cutting a recording into demonstrations and phases (``data.demos``).

In this order, each step inside the pieces of the step before:

1. one demonstration per file (cell, group); ``split_on_gap`` cuts where consecutive stamps
   are further apart than that many seconds;
2. ``ranges`` keep only the given spans: a list of [start, end] seconds from the file's first
   sample (then no split on gaps), or per demonstration ``{index: [[start, end], ...]}``
   in seconds from that demonstration's first sample (demonstrations not named are dropped);
   each range is one demonstration;
3. ``where``: each stretch where a signal's norm passes its level (contact force above 5 N,
   gripper closed) is one demonstration;
4. ``min_duration`` drops pieces shorter than that many seconds;
5. ``window`` cuts every piece into fixed pieces of that many seconds (continuous recordings).

:func:`resegment` applies the same inside the demonstrations of an already assembled
dataset (canonical HDF5), carrying train/test masks.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, group_rows
from ccl_cli.errors import InputError
from ccl_cli.io.options import DemoOptions

#: the demos options that cut streams and canonical files (the others name HDF5 groups,
#: datasets or .mat variables)
CUTS = ("split_on_gap", "ranges", "where", "min_duration", "window", "per_file")


def segment_ids(t_s: np.ndarray, demos: DemoOptions | Mapping[str, Any] | None, where: str,
                passes: np.ndarray | None = None) -> np.ndarray:
    """Demo id per sample (−1 = cut away) of one recording from the ``demos`` options
    (steps 1–5 of the module docstring); ``passes`` (N,) bool: where the ``demos.where``
    signal passes its level. t_s (N,) seconds → (N,) int. Nothing left is an InputError."""
    ids, _ = cut(t_s, demos, where, passes)
    if len(ids) and (ids < 0).all():
        raise InputError(f"{where}: no samples left after the demos cuts ({_given(demos)})")
    return ids


def _given(demos: DemoOptions | Mapping[str, Any] | None) -> str:
    demos = DemoOptions.from_mapping(demos)
    return ", ".join(f"demos.{k}" for k in sorted(demos.given()))


def cut(t_s: np.ndarray, demos: DemoOptions | Mapping[str, Any] | None, where: str,
        passes: np.ndarray | None = None, first: int = 0) -> tuple[np.ndarray, int]:
    """Demo id per sample (−1 = cut away) and the number of demonstrations before the phase
    cuts (step 1: the index ``demos.ranges`` keys refer to, counted from ``first``).

    ``passes`` (N,) bool is required with ``demos.where`` (the caller reads the signal). Ids
    are consecutive from 0 in time order. Loops run over demonstrations, never samples.
    """
    demos = DemoOptions.from_mapping(demos, where, "demos")
    other = demos.given() - set(CUTS)
    if other:
        raise InputError(f"{where}: demos: unknown option(s) {', '.join(sorted(other))} "
                         f"(use {', '.join(CUTS)})")
    n = len(t_s)
    if n == 0:
        return np.zeros(0, dtype=int), 0
    if isinstance(demos.ranges, list):
        ids = np.full(n, -1)
        rel = t_s - t_s[0]
        for k, (start, end) in enumerate(demos.ranges):
            inside = (rel >= start) & (rel <= end) & (ids < 0)
            ids[inside] = k
        n_base = 1
    else:
        ids = np.zeros(n, dtype=int)
        if demos.split_on_gap is not None:
            ids = np.concatenate([[0], np.cumsum(np.diff(t_s) > demos.split_on_gap)])
        n_base = int(ids[-1]) + 1
        if demos.ranges is not None:
            ids = _ranges_per_demo(t_s, ids, demos.ranges, first)
    if demos.where is not None:
        if passes is None or len(passes) != n:
            raise InputError(f"{where}: demos.where needs its signal at every state sample")
        ids = np.where(passes, ids, -1)
    if demos.given() & {"ranges", "split_on_gap", "where"}:
        ids = _runs(ids)  # else ids are all 0: one run, numbered 0 already
    if demos.min_duration is not None:
        ids = _at_least(t_s, ids, float(demos.min_duration))
    if demos.window is not None:
        ids = cut_windows(t_s, ids, float(demos.window))
    return ids, n_base


def _ranges_per_demo(t_s: np.ndarray, ids: np.ndarray, ranges: dict[int, list[list[float]]], first: int
                     ) -> np.ndarray:
    """Per demonstration j (ids ≥ 0), the samples inside ``ranges[first + j]`` (seconds from its
    first sample); each range a new id (not yet consecutive); −1 elsewhere."""
    out = np.full(len(t_s), -1)
    starts = np.flatnonzero(np.r_[True, ids[1:] != ids[:-1]])
    label = 0
    for s in starts:  # a loop over demonstrations
        j = int(ids[s])
        rows = ids == j
        rel = t_s - t_s[s]
        for start, end in ranges.get(first + j, []):
            inside = rows & (rel >= start) & (rel <= end) & (out < 0)
            out[inside] = label
            label += 1
    return out


def _runs(ids: np.ndarray) -> np.ndarray:
    """Each contiguous run of equal ids ≥ 0 a demonstration, numbered 0, 1, ... in time order."""
    keep = ids >= 0
    change = np.r_[True, ids[1:] != ids[:-1]] & keep
    return np.where(keep, np.cumsum(change) - 1, -1)


def _at_least(t_s: np.ndarray, ids: np.ndarray, seconds: float) -> np.ndarray:
    """Runs (consecutive ids ≥ 0) spanning less than ``seconds`` dropped, the rest renumbered."""
    keep = ids >= 0
    if not keep.any():
        return ids
    k = ids[keep]
    tk = t_s[keep]
    count = int(k.max()) + 1
    span = np.full(count, -np.inf)
    lo = np.full(count, np.inf)
    np.maximum.at(span, k, tk)
    np.minimum.at(lo, k, tk)
    long = (span - lo) >= seconds
    out = ids.copy()
    out[keep] = np.where(long[k], np.cumsum(long)[k] - 1, -1)
    return out


def cut_windows(t_s: np.ndarray, ids: np.ndarray, window: float) -> np.ndarray:
    """Cut each contiguous run of equal ``ids`` (≥ 0) into windows of ``window`` seconds
    from the run's first stamp; a last window shorter than ``window``/2 joins the one
    before it; −1 stays −1. Returns consecutive ids 0, 1, ... in time order."""
    n = len(t_s)
    if n == 0:
        return ids
    start = np.r_[True, ids[1:] != ids[:-1]]
    run = np.cumsum(start) - 1
    first = np.flatnonzero(start)
    last = np.r_[first[1:], n] - 1
    rel = t_s - t_s[first][run]
    k = np.floor(rel / window).astype(int)
    span = t_s[last] - t_s[first]  # per run
    k_last = np.floor(span / window).astype(int)
    short_tail = (span - k_last * window < window / 2) & (k_last > 0)
    k = np.where((k == k_last[run]) & short_tail[run], k - 1, k)
    change = np.r_[True, (run[1:] != run[:-1]) | (k[1:] != k[:-1])]
    out = np.cumsum(change & (ids >= 0)) - 1
    return np.where(ids >= 0, out, -1)


def resegment(data: Demonstrations, demos: DemoOptions | Mapping[str, Any] | None, where: str,
              masks: dict[str, list[int]] | None = None
              ) -> tuple[Demonstrations, dict[str, list[int]] | None]:
    """Apply the ``demos`` options inside each demonstration of an already assembled dataset
    (canonical HDF5): gaps, ranges (a list: seconds from each demonstration's first sample;
    per demonstration: keyed by its position 0, 1, ... in the file), minimum durations and
    windows. Samples cut away are dropped. Train/test ``masks`` (lists of demo ids) are
    carried over: each new piece keeps the membership of the demonstration it came from.
    Returns the re-cut dataset and masks."""
    demos = DemoOptions.from_mapping(demos, where, "demos")
    if not demos.given():
        return data, masks
    if demos.where is not None:
        raise InputError(f"{where}: demos.where applies to CSV, bag, MCAP and .mat recordings; "
                         "use demos.ranges here")
    new = np.full(data.n_samples, -1)
    parent: list[int] = []
    first = 0
    of_demo = dict(zip(*group_rows(data.demo), strict=True))
    for d in data.demo_ids:  # loop over demonstrations, not samples
        rows = of_demo[d]
        ids, n_base = cut(data.t[rows], demos, f"{where}: demo {int(d)}", first=first)
        first += n_base
        inside = ids >= 0
        new[rows[inside]] = ids[inside] + len(parent)
        parent += [int(d)] * (int(ids.max()) + 1 if inside.any() else 0)
    keep = new >= 0
    if not keep.any():
        raise InputError(f"{where}: no samples left after the demos cuts ({_given(demos)})")
    out = data.subset(keep)
    out.demo = new[keep]
    out.metadata = {**data.metadata, "demos": demos.model_dump(exclude_none=True)}
    if masks:
        parent_arr = np.asarray(parent)
        masks = {name: [int(i) for i in np.flatnonzero(np.isin(parent_arr, ids))]
                 for name, ids in masks.items()}
    return out, masks
