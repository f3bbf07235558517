"""What ``ccl inspect`` reports of what was read: rates over the active time, the
demonstrations a gap split finds, counts and names of an assembled dataset.

The gap is ``--gap``, else the config's ``data.demos.split_on_gap``, else
:data:`GAP_INTERVALS` times the median sampling interval: a 500 Hz stream recorded in
bursts shows 500 Hz, not its average over the pauses.
"""

from __future__ import annotations

import copy
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, group_rows

#: Default gap: a pause longer than this many median sampling intervals starts a new demonstration.
GAP_INTERVALS = 5.0


def activity(t_ns: np.ndarray, gap_s: float | None = None) -> dict[str, Any]:
    """Rate over the active time and the demonstrations of timestamps ``t_ns`` (n,).

    Intervals longer than ``gap_s`` (default GAP_INTERVALS × the median interval) are
    pauses: rate = (intervals that are not pauses) / (their summed duration);
    demos = pauses + 1."""
    t = np.sort(np.asarray(t_ns, dtype=np.int64))
    if t.size < 2:
        return {"rate_hz": None, "active_s": 0.0, "demos": int(t.size > 0), "gap_s": gap_s}
    dt = np.diff(t) / 1e9
    rule = None
    if gap_s is None:
        med = float(np.median(dt))
        gap_s, rule = GAP_INTERVALS * med, f"{GAP_INTERVALS:g} × median interval"
    pause = dt > gap_s
    active = float(dt[~pause].sum())
    out = {"rate_hz": float((~pause).sum() / active) if active > 0 else None, "active_s": active,
           "demos": int(pause.sum()) + 1, "gap_s": float(gap_s)}
    return out | ({"gap_rule": rule} if rule else {})


def summary(data: Demonstrations) -> dict[str, Any]:
    """Counts and names of what a reader produced (and, with a force channel, its median magnitude in
    the base frame)."""
    counts = np.bincount(np.unique(data.demo, return_inverse=True)[1])
    rows = dict(zip(*group_rows(data.demo), strict=True))
    return {"samples": data.n_samples, "demos": int(data.n_demos), "state_names": data.state_names,
            "action_names": data.action_names, "samples_per_demo": counts.tolist(),
            "duration_s": float(sum(np.ptp(data.t[rows[d]]) for d in data.demo_ids)),
            **({"force": {"frame": "base", "median_norm": float(np.median(np.linalg.norm(data.force, 1)))}}
               if data.force is not None else {})}


def repairs(data: Demonstrations) -> list[dict[str, Any]]:
    """What the sensor-fault repair did, per demonstration (:class:`~ccl_cli.dataset.Repair`):
    one entry per demonstration, action and fault — ``demo`` (its id in the data), ``action``
    (``mirrored``, ``restamped``, ``dropped``; ``kept`` for a fault kept as recorded), ``fault``,
    ``samples`` and ``times``: [first, last] of each run of such samples, in s from the
    demonstration's first sample (a dropped sample at the time between the samples on either
    side). Samples with no place in the data (left out by the demonstrations' options) and the
    gaps (pauses, in the stamps' findings) are not listed. Computed once per data
    (:meth:`~ccl_cli.dataset.Demonstrations.memo`: a run records it in run.json, in each saved
    model and in a check); each caller gets its own copy."""
    return copy.deepcopy(data.memo("repairs", lambda: _repairs(data)))


def _repairs(data: Demonstrations) -> list[dict[str, Any]]:
    rep = data.repair
    if rep is None or not len(rep.row):
        return []
    a, b, w = rep.places(data.demo)
    listed = (a >= 0) & ((rep.done != 0) | (rep.why != 0))
    gap = rep.faults.index("gap") if "gap" in rep.faults else -1
    listed &= (rep.done != 0) | (rep.why != gap)
    k = np.flatnonzero(listed)
    if not len(k):
        return []
    demo = data.demo[a[k]]
    t = (1 - w[k]) * data.t[a[k]] + w[k] * data.t[b[k]]
    ids, first = np.unique(data.demo, return_index=True)
    t -= data.t[first[np.searchsorted(ids, demo)]]
    key = np.stack([demo, rep.done[k], rep.why[k]], 1)
    new = np.r_[True, (key[1:] != key[:-1]).any(1) | (np.diff(k) > 1)]  # a run: consecutive samples alike
    start = np.flatnonzero(new)
    stop = np.r_[start[1:], len(k)]
    out: dict[tuple[int, int, int], dict[str, Any]] = {}
    for s, e in zip(start, stop, strict=True):  # a loop over runs of repaired samples
        d, act, why = (int(v) for v in key[s])
        entry = out.setdefault((d, act, why), {"demo": d, "action": rep.ACTIONS[act],
                                              "fault": rep.faults[why], "samples": 0, "times": []})
        entry["samples"] += int(e - s)
        entry["times"].append([float(t[s]), float(t[e - 1])])
    return [out[key] for key in sorted(out)]
