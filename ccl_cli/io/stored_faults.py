"""Sensor faults of recordings read as arrays — canonical HDF5, HDF5 layouts, .mat — found and
handled as the stream readers handle them (:mod:`ccl_cli.io.faults`), plus what a repair means for
actions stored beside the positions.

Positions go through :func:`~ccl_cli.io.faults.clean_positions` (stamps, hemisphere flips, spikes,
as ``data.faults`` says). When the actions are derived by ccl they are derived afterwards, from the
repaired positions. When they are stored in the file, whoever wrote it may have derived them from
the faulty positions, or recorded them with another sensor; ccl cannot know which, so

* a stored action whose sample lies within a derivative window (ccl's default at the recording's
  rate, ±``DERIVATIVE_HALF_SPAN_S``) of a flip's end or of a dropped spike is dropped with it —
  a derivative across the jump is garbage, and a few samples are all that is lost otherwise;
* inside a flip mirrored back, the stored actions of that stretch are mirrored as well when they
  follow the recorded positions — Σ uₙ·ẋₙ > 0 over the stretch's inner samples, ẋ the central
  difference of the positions as recorded (mirrored) — and kept as stored when they do not.

Everything is batched over samples; shapes: t (N,) s, X (N, p), U (N, q), demo (N,).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, Repair
from ccl_cli.io.derivative import default_window
from ccl_cli.io.faults import Cleaned, Finding, clean_positions, repair_record, run_edges, runs
from ccl_cli.io.options import FaultOptions

#: The fewest samples the fault checks look at (the spike test's stencil).
MIN_SAMPLES = 5


@dataclass
class Repaired:
    """A recording after its fault checks: ``keep`` (N,) the input samples kept; t (M,), X (M, p),
    U (M, q) or None, repaired; ``report`` the findings (counts, index and time ranges in the
    input's samples and stamps) as :mod:`ccl_cli.diagnostics` reads them; ``record`` what was
    done to each input sample and why."""

    keep: np.ndarray
    t: np.ndarray
    X: np.ndarray
    U: np.ndarray | None
    report: list[dict[str, Any]]
    record: Repair


def check_positions(t: np.ndarray, X: np.ndarray, demo: np.ndarray, options: FaultOptions
                    ) -> Cleaned | None:
    """:func:`~ccl_cli.io.faults.clean_positions` as ``options`` says, on t (N,), X (N, p) and
    demonstration ids (N,); None when nothing was found (or too few samples to look)."""
    if len(t) < MIN_SAMPLES:
        return None
    cleaned = clean_positions(t, X, demo, flips=options.flips, drop_spikes=options.spikes == "drop",
                              stamps=options.stamps == "repair")
    return cleaned if cleaned.findings else None


def repair_recording(t: np.ndarray, X: np.ndarray, U: np.ndarray | None, demo: np.ndarray,
                     options: FaultOptions) -> Repaired | None:
    """The fault checks of a recording of positions X with stored actions U (None: ccl derives
    them afterwards from the repaired positions); None when nothing was found."""
    cleaned = check_positions(t, X, demo, options)
    if cleaned is None:
        return None
    report = cleaned.report(t)
    if U is None:
        return Repaired(cleaned.keep, cleaned.t, cleaned.X, None, report, cleaned.record())
    near = _near_repairs(cleaned.findings, t, demo)
    U = _mirror_followers(U, X, t, demo, cleaned.findings)
    keep = cleaned.keep & ~near
    kept = ~near[cleaned.keep]  # of the samples clean_positions kept
    lost = near & cleaned.keep
    findings = list(cleaned.findings)
    if lost.any():
        findings.append(Finding("action_near_fault", lost, "dropped",
                                {"window_samples": int(2 * _reach(t, demo) + 1)}))
        report.append(findings[-1].as_dict(t))
    return Repaired(keep, cleaned.t[kept], cleaned.X[kept], U[keep], report, repair_record(findings, keep))


def _reach(t: np.ndarray, demo: np.ndarray) -> int:
    """Half of ccl's default derivative window at the recording's rate, in samples."""
    return default_window(t, demo)[0] // 2


def _near_repairs(findings: list[Finding], t: np.ndarray, demo: np.ndarray) -> np.ndarray:
    """Samples (N,) within :func:`_reach` of a flip's ends (the last sample before the jump and
    the first after it) or of a dropped spike (mirrored or dropped: faults kept as recorded
    change nothing)."""
    near = np.zeros(len(t), dtype=bool)
    reach = _reach(t, demo)
    for f in findings:  # a loop over the kinds of fault
        if f.action != "reported" and f.kind in ("hemisphere_flip", "spike"):
            near |= run_edges(f.mask, reach + 1 if f.kind == "hemisphere_flip" else reach)
    return near


def _mirror_followers(U: np.ndarray, X: np.ndarray, t: np.ndarray, demo: np.ndarray,
                      findings: list[Finding]) -> np.ndarray:
    """U (N, q) with each flip mirrored back negated where its stored actions follow the
    recorded positions X (N, p): Σ uₙ·ẋₙ > 0 over the stretch (p = q; else U as stored)."""
    flips = [f for f in findings if f.kind == "hemisphere_flip" and f.action == "mirrored"]
    if not flips or U.shape[1] != X.shape[1]:
        return U
    mask = flips[0].mask
    r = runs(mask)
    velocity = np.gradient(X, t, axis=0) if len(t) > 1 else np.zeros_like(X)
    # the central difference of a run's inner samples only (at its ends it spans the jump)
    inner = mask & np.r_[False, mask[:-1]] & np.r_[mask[1:], False]
    inner &= np.r_[False, demo[1:] == demo[:-1]] & np.r_[demo[1:] == demo[:-1], False]
    dots = np.where(inner, np.einsum("nq,nq->n", U, velocity), 0.0)
    label = np.cumsum(np.r_[mask[0], mask[1:] & ~mask[:-1]]) - 1  # the run each sample is in
    follows = np.bincount(label[mask], weights=dots[mask], minlength=len(r)) > 0
    out = U.copy()
    flip = mask & follows[np.maximum(label, 0)]
    out[flip] = -out[flip]
    return out


def repair_dataset(data: Demonstrations, options: FaultOptions) -> Demonstrations:
    """``data`` (positions X with stored actions U) after :func:`repair_recording`: the kept
    samples (ground truth with them), repaired, the findings in ``metadata["faults"]``."""
    fixed = repair_recording(data.t, data.X, data.U, data.demo, options)
    if fixed is None:
        data.repair = Repair.untouched(data.n_samples)
        return data
    out = data.subset(fixed.keep)
    out.t, out.X, out.U = fixed.t, fixed.X, fixed.U
    out.metadata = {**data.metadata, "faults": fixed.report}
    out.repair = fixed.record
    return out
