"""Cutting a recording into demonstrations (``data.demos``).

One demonstration per file by default; ``split_on_gap`` cuts where consecutive stamps are
further apart than that many seconds; ``ranges`` keep only the given spans (seconds from
the first sample); ``window`` then cuts every resulting segment into fixed pieces of that
many seconds (continuous recordings). :func:`resegment` applies the same inside the
demonstrations of an already assembled dataset (canonical HDF5), carrying train/test masks.
"""

from __future__ import annotations

from collections.abc import Mapping
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.io.options import DemoOptions

#: the demos options that cut streams and canonical files (the others name HDF5 groups,
#: datasets or .mat variables)
CUTS = ("split_on_gap", "ranges", "window", "per_file")


def segment_ids(t_s: np.ndarray, demos: DemoOptions | Mapping[str, Any] | None, where: str) -> np.ndarray:
    """Demo id per sample (−1 = outside every range) from the ``demos`` options.

    ``ranges`` keep the samples within [start, end] seconds of the first sample (one
    demonstration per range), else ``split_on_gap`` cuts at the pauses, else one
    demonstration; ``window`` then cuts each of them into pieces of ``window`` seconds (see
    :func:`cut_windows`). t_s (N,) seconds → (N,) int.
    """
    demos = DemoOptions.from_mapping(demos, where, "demos")
    other = demos.given() - set(CUTS)
    if other:
        raise InputError(f"{where}: demos: unknown option(s) {', '.join(sorted(other))} "
                         "(use split_on_gap, ranges, window or per_file)")
    n = len(t_s)
    if demos.ranges is not None:
        ids = np.full(n, -1)
        rel = t_s - t_s[0]
        for k, (start, end) in enumerate(demos.ranges):
            inside = (rel >= start) & (rel <= end) & (ids < 0)
            ids[inside] = k
        if (ids < 0).all():
            raise InputError(f"{where}: no samples inside demos.ranges")
    elif demos.split_on_gap is not None:
        ids = np.concatenate([[0], np.cumsum(np.diff(t_s) > demos.split_on_gap)])
    else:
        ids = np.zeros(n, dtype=int)
    if demos.window is not None:
        ids = cut_windows(t_s, ids, float(demos.window))
    return ids


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
    (canonical HDF5): gaps, ranges (seconds from each demonstration's first sample) and
    windows. Samples outside every range are dropped. Train/test ``masks`` (lists of demo
    ids) are carried over: each new piece keeps the membership of the demonstration it came
    from. Returns the re-cut dataset and masks."""
    demos = DemoOptions.from_mapping(demos, where, "demos")
    if not demos.given():
        return data, masks
    new = np.full(data.n_samples, -1)
    parent: list[int] = []
    for d in data.demo_ids:  # loop over demonstrations, not samples
        rows = np.flatnonzero(data.demo == d)
        ids = segment_ids(data.t[rows], demos, f"{where}: demo {int(d)}")
        inside = ids >= 0
        new[rows[inside]] = ids[inside] + len(parent)
        parent += [int(d)] * (int(ids.max()) + 1 if inside.any() else 0)
    keep = new >= 0
    out = data.subset(keep)
    out.demo = new[keep]
    out.metadata = {**data.metadata, "demos": demos.model_dump(exclude_none=True)}
    if masks:
        parent_arr = np.asarray(parent)
        masks = {name: [int(i) for i in np.flatnonzero(np.isin(parent_arr, ids))]
                 for name, ids in masks.items()}
    return out, masks
