"""What ``ccl inspect`` reports of what was read: rates over the active time, the
demonstrations a gap split finds, counts and names of an assembled dataset.

The gap is ``--gap``, else the config's ``data.demos.split_on_gap``, else
:data:`GAP_INTERVALS` times the median sampling interval: a 500 Hz stream recorded in
bursts shows 500 Hz, not its average over the pauses.
"""

from __future__ import annotations

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
    """Counts and names of what a reader produced."""
    counts = np.bincount(np.unique(data.demo, return_inverse=True)[1])
    rows = dict(zip(*group_rows(data.demo), strict=True))
    return {"samples": data.n_samples, "demos": int(data.n_demos), "state_names": data.state_names,
            "action_names": data.action_names, "samples_per_demo": counts.tolist(),
            "duration_s": float(sum(np.ptp(data.t[rows[d]]) for d in data.demo_ids))}
