"""Data checks that return coded warnings (ALGORITHMS.md §1 data model, §3.4 identifiability).

Each check returns a list of ``{"code": ..., "message": ...}`` dicts; the pipeline keeps
them in ``Pipeline.warnings``, the run puts them in ``--json``/``run.json`` and report.md
(:func:`ccl_cli.render.report.diagnostics_lines`), and :func:`emit` logs each as
``warning: <message>`` (the CLI prints ``ccl: warning: ...`` on stderr).

Codes: ``constant_dimension``, ``no_motion``, ``noisy_actions``, ``few_demos``,
``short_demos``, ``low_rank_actions``, ``duplicate_stamps``, ``jittery_stamps``.

Noise levels are estimated from the data alone, per dimension and inside each
demonstration, from second differences (MAD, robust to the smooth motion):
σ̂² = (median|Δ²y| / 0.6745)² / 6 for white noise on y. Actions derived from the states
(the readers' local polynomial) carry the states' noise through the derivative filter c
(uniform stamps): σ̂²_u = σ̂²_x Σc². Recorded actions are taken as white. The signal-to-noise
ratio of y is SNR = Σ var(y_j) / Σ σ̂²_j (1 for pure noise).

Thresholds were chosen by measurement on simulated recordings (docs/measurements.md,
"Diagnostics"; ``python benchmarks/diagnostics_thresholds.py``).
"""

from __future__ import annotations

import logging
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, group_rows
from ccl_cli.errors import InputError
from ccl_cli.learn import defaults as _defaults
from ccl_cli.learn import model_selection as _selection
from ccl_cli.learn.noise import white_noise_var

log = logging.getLogger("ccl")

#: No motion: action SNR below this and the states within STILL_BAND of their magnitude.
NO_MOTION_SNR = 3.0
#: States move no more than this fraction of their magnitude (max std / RMS of the mean).
STILL_BAND = 0.05
#: Noisy actions (the states move smoothly, SNR_x ≥ SMOOTH_STATE_SNR): action SNR below this.
NOISY_ACTION_SNR = 3.0
SMOOTH_STATE_SNR = 100.0
#: A dimension is constant when its std ≤ 1e-12·(1 + |mean|), near-constant when its std is
#: below NEAR_CONSTANT of the largest std among the dimensions of the same kind.
NEAR_CONSTANT = 1e-3
#: Fewer demonstrations than this: cross-validation falls back to time blocks (selection.MIN_DEMOS);
#: fewer than TEST_MIN_DEMOS: the held-out test set too.
MIN_DEMOS = _selection.MIN_DEMOS
TEST_MIN_DEMOS = _defaults.TEST_MIN_DEMOS
#: Demonstrations shorter than this (samples) are too short to derive, split or learn from.
MIN_DEMO_SAMPLES = 10
#: Directions whose action variance is below RANK_NOISE × the noise variance (or below
#: RANK_RELATIVE × the largest) are not moved.
RANK_NOISE = 3.0
RANK_RELATIVE = 1e-4
#: Stamp jitter: robust spread of the sampling intervals above this fraction of their median.
JITTER = 0.1

CODES = ("constant_dimension", "no_motion", "noisy_actions", "few_demos", "short_demos",
         "low_rank_actions", "duplicate_stamps", "jittery_stamps", "hemisphere_flips", "spikes",
         "stamp_faults", "overfit", "no_better_than_baseline", "constraint_does_not_hold",
         "constraint_varies", "not_identifiable", "actions_near_faults", "far_from_truth",
         "no_heldout_support", "degenerate_input", "repeated_poses", "not_judged")
#: Sensor faults the readers found (:mod:`ccl_cli.io.faults`) → (warning code, what they are,
#: the config key that keeps them); gaps are pauses or lost samples, stated in the report only.
FAULTS = {"hemisphere_flip": ("hemisphere_flips", "hemisphere flip(s) of the tracker (positions "
                                                  "mirrored through the transmitter)", "flips: keep"),
          "spike": ("spikes", "spike(s) in the states", "spikes: keep"),
          "duplicate_sample": ("stamp_faults", "duplicated sample(s)", "stamps: keep"),
          "repeated_pose": ("repeated_poses", "repeated pose(s)", "stamps: keep"),
          "bad_stamp": ("stamp_faults", "repeated or misplaced stamp(s)", "stamps: keep"),
          "backward_stamp": ("stamp_faults", "clock step(s) back", "stamps: keep"),
          "clock_step": ("stamp_faults", "clock step(s) forward", "stamps: keep"),
          "action_near_fault": ("actions_near_faults", "stretch(es) of actions stored in the file within a "
                                "derivative window of a repaired position (a derivative across the fault)",
                                "flips: keep, spikes: keep")}


def warning(code: str, message: str) -> dict[str, str]:
    """One coded warning ``{"code", "message"}`` (codes listed in :data:`CODES`)."""
    if code not in CODES:
        raise ValueError(f"unknown diagnostic code {code!r}")
    return {"code": code, "message": message}


def emit(warnings: list[dict[str, str]]) -> list[dict[str, str]]:
    """Log each warning as ``warning: <message>`` on the ``ccl`` logger; returns them."""
    for w in warnings:
        log.warning("warning: %s", w["message"])
    return warnings


# -- noise estimates (ccl_cli.learn.noise) ------------------------------------------------------
def noise_levels(data: Demonstrations) -> dict[str, Any]:
    """Estimated noise variances and SNRs of states and actions.

    Returns ``x_noise`` (p,), ``u_noise`` (q,), ``snr_x``, ``snr_u`` (floats),
    ``band_x`` (max std of a state / RMS of the state's mean), ``derived`` (bool|None) and
    ``temporal``: whether the samples are trajectories in time (states smooth, SNR_x ≥
    SMOOTH_STATE_SNR, or at rest, band_x < STILL_BAND), without which differences in time
    say nothing about noise. Computed once per data (:meth:`Demonstrations.memo`): a run's
    checks ask for the training part's three times.
    """
    return dict(data.memo("noise_levels", lambda: _noise_levels(data)))


def _noise_levels(data: Demonstrations) -> dict[str, Any]:
    X, U, demo = data.X, data.U, data.demo
    x_noise = white_noise_var(X, demo)
    u_white = white_noise_var(U, demo)
    how = data.derivative
    derived = how.derived
    dt = _median_step(data)
    if data.n_state == data.n_action and derived is not False and dt > 0:
        via_x = x_noise * how.gain(dt)
        u_noise = via_x if derived else np.maximum(u_white, via_x)
    else:
        u_noise = u_white
    var_x = X.var(0, ddof=1) if len(X) > 1 else np.zeros(data.n_state)
    var_u = U.var(0, ddof=1) if len(U) > 1 else np.zeros(data.n_action)
    mean_rms = float(np.sqrt(np.mean(X.mean(0) ** 2)))
    snr_x = _ratio(var_x.sum(), x_noise.sum())
    band_x = _ratio(float(np.sqrt(var_x.max())), mean_rms)
    return {"x_noise": x_noise, "u_noise": u_noise, "snr_x": snr_x,
            "snr_u": _ratio(var_u.sum(), u_noise.sum()), "band_x": band_x, "derived": derived,
            "temporal": bool(snr_x >= SMOOTH_STATE_SNR or band_x < STILL_BAND)}


def _ratio(a: float, b: float) -> float:
    if b > 0:
        return float(a / b)
    return float("inf") if a > 0 else float("nan")


def _median_step(data: Demonstrations) -> float:
    dt = np.diff(data.t)[data.demo[1:] == data.demo[:-1]]
    dt = dt[dt > 0]
    return float(np.median(dt)) if len(dt) else 0.0


# -- the checks -----------------------------------------------------------------------------
def constant_dimensions(data: Demonstrations) -> list[dict[str, str]]:
    """``constant_dimension``: states or actions that never change (std ≤ 1e-12(1 + |mean|))
    or barely change (std < NEAR_CONSTANT × the largest std of the same kind), by name."""
    out = []
    for kind, Y, names in (("state", data.X, data.state_names), ("action", data.U, data.action_names)):
        if len(Y) < 2:
            continue
        std, mean = Y.std(0), Y.mean(0)
        const = std <= 1e-12 * (1 + np.abs(mean))
        near = ~const & (std < NEAR_CONSTANT * std.max())
        if const.any():
            listed = ", ".join(f"{names[j]} = {mean[j]:.6g}" for j in np.flatnonzero(const))
            why = ("it never moves; a constant action counts as a constraint" if kind == "action"
                   else "a constant state carries no information")
            out.append(warning("constant_dimension", f"{kind} dimension(s) constant: {listed} ({why})"))
        if near.any():
            listed = ", ".join(f"{names[j]} (std {std[j]:.3g})" for j in np.flatnonzero(near))
            out.append(warning("constant_dimension",
                               f"{kind} dimension(s) nearly constant: {listed}, below "
                               f"{NEAR_CONSTANT:g} of the largest {kind} std {std.max():.3g}"))
    return out


def motion(data: Demonstrations, levels: dict[str, Any] | None = None) -> list[dict[str, str]]:
    """``no_motion`` (the actions are at their noise level and the states stay put) and
    ``noisy_actions`` (the states move smoothly but the actions are mostly noise)."""
    lv = levels or noise_levels(data)
    snr_u, snr_x, band = lv["snr_u"], lv["snr_x"], lv["band_x"]
    if not np.isfinite(snr_u) and np.isnan(snr_u):
        return [warning("no_motion", "no motion: every action is constant")]
    if snr_u < NO_MOTION_SNR and band < STILL_BAND:
        return [warning("no_motion",
                        f"no motion: the actions are at their noise level (signal-to-noise ratio "
                        f"{snr_u:.2g}, < {NO_MOTION_SNR:g}) and the states stay within {100 * band:.2g} % of "
                        "their magnitude; the recording looks at rest, and any constraint learnt from "
                        "it describes noise")]
    if snr_u < NOISY_ACTION_SNR and snr_x >= SMOOTH_STATE_SNR:
        hint = (" (derived velocities: widen data.action.window)" if lv["derived"] else "")
        return [warning("noisy_actions",
                        f"noisy actions: the states move smoothly but the actions are mostly noise "
                        f"(signal-to-noise ratio {snr_u:.2g}, < {NOISY_ACTION_SNR:g}){hint}")]
    return []


def demonstrations(data: Demonstrations) -> list[dict[str, str]]:
    """``few_demos`` (fewer than MIN_DEMOS) and ``short_demos`` (any shorter than
    MIN_DEMO_SAMPLES samples)."""
    out = []
    n = data.n_demos
    if n < MIN_DEMOS:
        cut = pause_split(data)
        advice = (f"the recordings pause {cut[2]} times for {cut[1]:.3g} s or more: data.demos: "
                  f"{{split_on_gap: {cut[0]:g}}} cuts them at their pauses into {cut[3]} demonstrations"
                  if cut is not None else "cut continuous recordings with data.demos: {window: S} (seconds) "
                  "or record more demonstrations")
        which = ("cross-validation uses" if n >= TEST_MIN_DEMOS else
                 "the held-out test set and cross-validation use")
        out.append(warning("few_demos",
                           f"only {n} demonstration{'s' if n != 1 else ''} (fewer than {MIN_DEMOS}): "
                           f"by default {which} contiguous time blocks rather than whole "
                           f"demonstrations; {advice}"))
    sizes = np.bincount(np.unique(data.demo, return_inverse=True)[1])
    short = int((sizes < MIN_DEMO_SAMPLES).sum())
    if short:
        out.append(warning("short_demos",
                           f"{short} of {n} demonstrations have fewer than {MIN_DEMO_SAMPLES} samples "
                           f"(shortest {int(sizes.min())})"))
    return out


def pause_split(data: Demonstrations) -> tuple[float, float, int, int] | None:
    """A ``split_on_gap`` that cuts the demonstrations at their pauses — intervals longer than
    GAP_INTERVALS (:mod:`ccl_cli.io.summary`) × the median interval — into at least MIN_DEMOS
    pieces of at least MIN_DEMO_SAMPLES samples: (the gap, a round value between that limit and
    half the shortest pause; the shortest pause, s; the pauses; the pieces), else None."""
    from ccl_cli.io.summary import GAP_INTERVALS

    inside = data.demo[1:] == data.demo[:-1]
    dt = np.diff(data.t)
    steps = dt[inside & (dt > 0)]
    if not len(steps):
        return None
    floor = GAP_INTERVALS * float(np.median(steps))
    pause = inside & (dt > floor)
    if not pause.any():
        return None
    shortest = float(dt[pause].min())
    gap = max(float(f"{0.5 * shortest:.1g}"), float(f"{floor:.2g}"))
    if gap <= floor or gap >= shortest:
        gap = float(f"{0.5 * (floor + shortest):.3g}")
    starts = np.r_[0, np.flatnonzero(~inside | pause) + 1, len(data.t)]
    pieces = int((np.diff(starts) >= MIN_DEMO_SAMPLES).sum())
    return (gap, shortest, int(pause.sum()), pieces) if pieces >= MIN_DEMOS else None


def stamps(data: Demonstrations) -> list[dict[str, str]]:
    """``duplicate_stamps`` (a sampling interval ≤ 0 inside a demonstration) and
    ``jittery_stamps`` (1.4826·MAD of the intervals, each relative to its demonstration's median
    interval, > JITTER: demonstrations logged at different but steady rates are not jittery)."""
    out = []
    inside = data.demo[1:] == data.demo[:-1]
    dt = np.diff(data.t)[inside]
    if not len(dt):
        return out
    dup = int((dt <= 0).sum())
    if dup:
        out.append(warning("duplicate_stamps",
                           f"{dup} samples repeat or precede the stamp of the sample before them"))
    ok = dt > 0
    pos, owner = dt[ok], data.demo[1:][inside][ok]
    if len(pos) >= 3:
        med = float(np.median(pos))
        own = median_by_group(pos, owner)
        spread = med * 1.4826 * float(np.median(np.abs(pos / own - 1.0)))
        if med > 0 and spread > JITTER * med:
            out.append(warning("jittery_stamps",
                               f"jittery stamps: the sampling interval varies by {100 * spread / med:.2g} % "
                               f"around {med:.3g} s ({1 / med:.3g} Hz); derivatives use the real stamps, "
                               "but stamp errors become velocity errors"))
    return out


def median_by_group(values: np.ndarray, groups: np.ndarray) -> np.ndarray:
    """Each value's group median (as ``np.median`` of the group's values): (n,) → (n,), by one
    sort of (group, value) — linear in the number of groups, not quadratic."""
    order = np.lexsort((values, groups))
    v, g = values[order], groups[order]
    starts = np.r_[0, np.flatnonzero(g[1:] != g[:-1]) + 1]
    counts = np.diff(np.r_[starts, len(v)])
    med = (v[starts + (counts - 1) // 2] + v[starts + counts // 2]) / 2
    out = np.empty_like(values, dtype=float)
    out[order] = np.repeat(med, counts)
    return out


def check_data(data: Demonstrations) -> list[dict[str, str]]:
    """Every data check (not the rank check, which needs the learnt s): a list of warnings."""
    levels = noise_levels(data)
    return [*sensor_faults(data), *constant_dimensions(data), *motion(data, levels), *demonstrations(data),
            *stamps(data)]


def _times(times: list[list[float]], limit: int = 4) -> str:
    shown = ", ".join(f"{a:.2f}–{b:.2f} s" if b > a else f"{a:.2f} s" for a, b in times[:limit])
    return shown + (f" and {len(times) - limit} more" if len(times) > limit else "")


def _samples(n: int) -> str:
    return f"{n} sample" + ("" if n == 1 else "s")


def sensor_faults(data: Demonstrations) -> list[dict[str, str]]:
    """One warning per kind of sensor fault the readers found in a file (``metadata`` of each
    file: ``faults``), with its count, what was done, where — per demonstration of the data with
    the times from its first sample (:func:`ccl_cli.io.summary.repairs`; else the time ranges from
    the file's first sample) — and the ``data.faults`` key that keeps them."""
    from ccl_cli.io.summary import repairs

    placed = repairs(data)
    out = []
    for entry in (data.metadata or {}).get("files", []):
        for f in (entry.get("faults") or []) if isinstance(entry, dict) else []:
            if f.get("kind") not in FAULTS or not f.get("count"):
                continue
            if f["kind"] == "repeated_pose":
                out.append(_repeats(entry.get("path"), f))
                continue
            code, what, keep = FAULTS[f["kind"]]
            done = "kept as recorded" if f.get("action") == "reported" else f["action"]
            fix = "" if f.get("action") == "reported" else f"; data.faults: {{{keep}}} keeps them"
            where = [r for r in placed if r["fault"] == f["kind"]
                     and r["demo"] in entry.get("demo_ids", [r["demo"]])]
            at = "; ".join(f"demonstration {r['demo']}: {_samples(r['samples'])} at {_times(r['times'])}"
                           for r in where[:6]) \
                + (f"; and {len(where) - 6} more demonstrations" if len(where) > 6 else "") if where else \
                f"at {_times(f.get('times') or [])} (from the file's start)"
            out.append(warning(code, f"{entry.get('path')}: {f['count']} {what}, {_samples(f['n_samples'])} "
                                     f"{done} — {at}{fix}"))
    return out


def _repeats(path: str | None, f: dict[str, Any]) -> dict[str, str]:
    """``repeated_poses``: the sensor's rate, the logging rate, and what was done with the
    repeats (a :func:`ccl_cli.io.faults.repeated_poses` finding as a dict)."""
    log_rate = f" logged at {f['log_rate_hz']:.3g} Hz" if f.get("log_rate_hz") else ""
    head = (f"{path}: repeated poses: the sensor updates at {f['rate_hz']:.3g} Hz, its samples were"
            f"{log_rate}: each pose is repeated {f['per_pose']:.3g} times (median) until the next")
    if f.get("action") == "reported":
        return warning("repeated_poses", f"{head}; kept as recorded (data.faults: {{stamps: keep}}): "
                       "velocities derived across a repeat are zero, then jump")
    return warning("repeated_poses", f"{head}; the {f['n_samples']} repeats were left out and learning "
                   f"uses the {f['poses']} poses at their first stamps (a pose held over several updates "
                   "keeps one sample per update); predict gives each repeat its pose's row (repair: "
                   "filled); data.faults: {stamps: keep} keeps them")


def action_rank(U: np.ndarray, noise_var: np.ndarray) -> int:
    """Number of directions the actions U (N, q) move in beyond their noise: eigenvalues of
    the second moment UᵀU/N above RANK_NOISE × the mean noise variance and RANK_RELATIVE ×
    the largest eigenvalue."""
    if len(U) == 0:
        return 0
    ev = np.linalg.eigvalsh(U.T @ U / len(U))
    floor = max(RANK_NOISE * float(np.mean(noise_var)), RANK_RELATIVE * float(ev.max()), np.finfo(float).tiny)
    return int((ev > floor).sum())


def low_rank_actions(data: Demonstrations, U: np.ndarray, n_constraints: int,
                     noise_var: np.ndarray | None = None) -> list[dict[str, str]]:
    """``low_rank_actions`` after learning s = ``n_constraints`` on the actions ``U`` (N, q)
    of ``data`` (the training set): the constraint is identifiable only when the actions
    span the q − s free directions (§3.4). Warns when their rank r < q − s, and when
    r = q − s but every training demonstration adds directions of its own (the rank is
    limited by the number of demonstrations, so s may count unexplored directions)."""
    q = U.shape[1]
    if noise_var is None:
        lv = noise_levels(data)
        noise_var = lv["u_noise"] if lv["temporal"] else np.zeros(q)
    r = action_rank(U, noise_var)
    free = q - int(n_constraints)
    if r < free:
        return [warning("low_rank_actions",
                        f"the training actions span {r} direction{'s' if r != 1 else ''} but {free} free "
                        f"directions (q − s = {q} − {n_constraints}) are needed to identify the constraint")]
    ids = data.demo_ids
    if len(ids) >= 2 and 0 < r < q:
        per = [action_rank(U[rows], noise_var) for rows in group_rows(data.demo)[1]]  # one per demonstration
        if sum(per) == r:
            return [warning("low_rank_actions",
                            f"each of the {len(ids)} training demonstrations moves along directions of its "
                            f"own ({r} in all, of q = {q}): s = {n_constraints} may count directions that "
                            "no demonstration explored; more demonstrations would tell")]
    return []


# -- verdicts of fitted stages -------------------------------------------------------------------
#: A stage is ``ok`` when its held-out evidence is; ``unjudged`` when it has no metric to judge
#: it by (a policy learnt alone from data without a true π); ``poor`` when a check below fails
#: (the run completes and says what is wrong); ``failed`` when it could not produce a result.
STATUSES = ("ok", "unjudged", "poor", "failed")
#: Overfit: a held-out error above OVERFIT_RATIO × the training error, and above OVERFIT_FLOOR
#: (below it both are at the level of noise and numerical error).
OVERFIT_RATIO = 10.0
OVERFIT_FLOOR = 1e-2
#: Policies: a normalised error at or above 1 is no better than predicting zero.
ZERO_LEVEL = 1.0


def overfit(stage: str, name: str, train: dict | None, test: dict | None) -> list[dict[str, str]]:
    """``overfit`` when the held-out value of metric ``name`` is OVERFIT_RATIO × its training
    value and above OVERFIT_FLOOR (metric dicts of metrics.json, or None)."""
    if not train or not test or not np.isfinite(train["value"]) or not np.isfinite(test["value"]):
        return []
    if test["value"] > OVERFIT_FLOOR and test["value"] > OVERFIT_RATIO * max(train["value"], 1e-300):
        return [warning("overfit", f"{stage}: held-out {name} {test['value']:.3g} is "
                                   f"{test['value'] / max(train['value'], 1e-300):.3g}× its training value "
                                   f"{train['value']:.3g}: the model does not generalise")]
    return []


def not_better(stage: str, name: str, test: dict | None, baseline: float, what: str) -> list[dict[str, str]]:
    """``no_better_than_baseline`` when the held-out ``test`` metric is not below ``baseline``
    (the same metric of ``what``, e.g. predicting zero) by at least its standard error."""
    if not test or not np.isfinite(test["value"]) or not np.isfinite(baseline):
        return []
    if test["value"] + (test.get("se") or 0.0) >= baseline:
        return [warning("no_better_than_baseline",
                        f"{stage}: held-out {name} {test['value']:.3g} is no better than {what} "
                        f"({baseline:.3g})")]
    return []


def constraint_evidence(model: Any, d: Demonstrations, Y: np.ndarray) -> dict[str, Any] | None:
    """How far the observations ``Y`` (N, q) of ``d`` move along the learnt constraint rows
    against their noise (:func:`ccl_cli.learn.constraint.noise_rank.row_evidence`): per row
    ``ratio`` (energy / noise) and ``share`` (of all the motion), and ``holds`` — every row at
    the noise level or a negligible share — or None when the data cannot tell (not a
    trajectory in time, or no motion).

    When the observations are the actions and these are the states' derivative, the positions'
    drift along the rows (:func:`~ccl_cli.learn.constraint.geometry.rows_drift`) is a second test
    (``drift``, ``limit``: :func:`~ccl_cli.learn.constraint.geometry.holds_limit`): compliance and
    tremor lift the motion along a true row far above the sensor's noise, but do not carry the
    states off it. The constraint holds when either test says so; when only the drift does not,
    ``measure`` is "drift".

    A model per stretch (per window or segment, or in stretches) speaks only for the stretches
    it was fitted on: on other data its rows would be a neighbouring stretch's. It is applied to
    ``d`` as a new recording by its own stated rule (the same kind and rows per stretch fitted
    there, as ``ccl evaluate`` does) and the evidence says so (``refitted``): whether k rows per
    stretch hold on these data. A model whose rule carries nothing over to new data (one model
    per demonstration, fitted anew on each) has no evidence to give: None."""
    from ccl_cli.learn.constraint import geometry, noise_rank

    if not getattr(model, "n_constraints_", 0) or not model.new_data_rule.carries_over:
        return None
    try:
        applied = model.applies_to(d.X, Y, groups=d.demo, t=d.t, new_recording=model.is_local)
        rows = applied.model.constraint(d.X, groups=d.demo, t=d.t)
    except InputError:
        return None  # no rows on these data
    how = d.derivative
    positions = bool(how.derived) and d.n_state == d.n_action
    out = None
    ev = noise_rank.row_evidence(Y, rows, d.demo, d.t, d.X if positions else None, how if positions else None)
    ratio = ev.energy / np.maximum(ev.noise, np.finfo(float).tiny)
    if ev.snr >= noise_rank.MIN_SNR and np.isfinite(ratio).all() and np.isfinite(ev.share).all():
        # (not: overflowing data tell nothing)
        holds = (ratio <= noise_rank.MARGIN) | (ev.share <= noise_rank.SHARE)
        out = {"ratio": ratio.tolist(), "share": ev.share.tolist(), "holds": bool(holds.all()),
               "refitted": applied.refitted}
    if Y is d.U and geometry.kinematic(d.X, d.U, d.demo, d.t, how)[0] and np.isfinite(d.X).all():
        # the actions are the states' derivative: a constraint keeps the states on its level sets,
        # whatever compliance or tremor adds to the velocities (learn/constraint/geometry.py) —
        # it holds when either test says so
        drift = geometry.model_drift(applied.model, rows, d.X, d.demo)
        limit = geometry.holds_limit(d.X, d.demo, rows.shape[1])
        kept = out or {"ratio": [], "share": ev.share.tolist(), "holds": False, "refitted": applied.refitted}
        if not kept["holds"] and np.isfinite(drift).all():
            return {**kept, "drift": drift.tolist(), "limit": limit, "holds": bool((drift <= limit).all()),
                    "measure": "drift"}
        return {**kept, "drift": drift.tolist(), "limit": limit}
    return out


def does_not_hold(stage: str, evidence: dict[str, Any] | None, where: str) -> list[dict[str, str]]:
    """``constraint_does_not_hold`` when a learnt row moves beyond the noise on ``where``."""
    from ccl_cli.learn.constraint.noise_rank import MARGIN, SHARE

    if evidence is None or evidence["holds"]:
        return []
    if evidence.get("measure") == "drift":
        k = next(i for i, v in enumerate(evidence["drift"]) if v > evidence["limit"])
        return [warning("constraint_does_not_hold",
                        f"{stage}: on the {where} the positions drift along learnt constraint row {k + 1} "
                        f"by {evidence['drift'][k]:.3g} of their spread (> {evidence['limit']:g}): the "
                        "constraint does not hold there")]
    k = next(i for i, (r, s) in enumerate(zip(evidence["ratio"], evidence["share"], strict=True))
             if r > MARGIN and s > SHARE)
    return [warning("constraint_does_not_hold",
                    f"{stage}: on the {where} the motion along learnt constraint row {k + 1} is "
                    f"{evidence['ratio'][k]:.3g}× its noise ({100 * evidence['share'][k]:.2g} % of all the "
                    "motion): the constraint does not hold there")]


#: A constant constraint varies when one demonstration's own rows lie more than VARIES_DEG
#: (largest principal angle) from the common ones and explain its actions VARIES_GAIN× better.
VARIES_DEG = 5.0
VARIES_GAIN = 2.0
#: A single recording is cut into stretches of about VARIES_WINDOW_S seconds (2 to 24 of them).
VARIES_WINDOW_S = 5.0


def _null_rows(Y: np.ndarray, s: int) -> tuple[np.ndarray, float]:
    """The s directions the actions Y (n, q) move least along (eigenvectors of YᵀY/n with the
    s smallest eigenvalues — the closed form of a constant constraint, ALGORITHMS.md §4.1)
    as rows (s, q), and the mean squared motion along them."""
    ev, vec = np.linalg.eigh(Y.T @ Y / max(len(Y), 1))
    return vec[:, :s].T, float(ev[:s].sum())


def _stretches(d: Demonstrations, blocks: int | None = None) -> list[tuple[str, np.ndarray]]:
    """(label, sample rows or mask) per demonstration, or for a single recording ``blocks``
    contiguous stretches of equal length in time (default: about VARIES_WINDOW_S each)."""
    if d.n_demos >= 2:
        rows = dict(zip(*group_rows(d.demo), strict=True))
        return [(f"demonstration {g}", rows[g]) for g in d.demo_ids]
    if blocks is None:
        blocks = int(np.clip(round(float(np.ptp(d.t)) / VARIES_WINDOW_S), 2, 24))
    edges = np.linspace(d.t.min(), d.t.max(), blocks + 1)
    part = np.clip(np.searchsorted(edges, d.t, side="right") - 1, 0, blocks - 1)
    return [(f"the stretch {edges[b] - edges[0]:.1f}–{edges[b + 1] - edges[0]:.1f} s", part == b)
            for b in range(blocks)]


def constraint_varies(stage: str, rows: np.ndarray, d: Demonstrations, Y: np.ndarray,
                      noise_var: np.ndarray | None = None, blocks: int | None = None) -> list[dict[str, str]]:
    """``constraint_varies`` for a constant constraint with rows (s, q) learnt on ``d`` (the
    training data; actions ``Y`` (N, q)): a demonstration (or, in a single recording, one of
    ``blocks`` stretches of time) whose own s rows lie more than VARIES_DEG from the common ones and
    leave VARIES_GAIN× less motion along them — the surface tilted or changed. Stretches
    whose actions do not span the q − s free directions cannot tell and are skipped."""
    s, q = rows.shape
    if s == 0:
        return []
    if noise_var is None:
        lv = noise_levels(d)
        noise_var = lv["u_noise"] if lv["temporal"] and len(lv["u_noise"]) == q else np.zeros(q)
    worst: tuple[float, str] | None = None
    for label, mask in _stretches(d, blocks):
        Yg = Y[mask]
        if len(Yg) < 3 * q or action_rank(Yg, noise_var) < q - s:
            continue
        own, own_motion = _null_rows(Yg, s)
        common_motion = float(np.mean(((Yg @ rows.T) ** 2).sum(1)))
        cosines = np.linalg.svd(own @ rows.T, compute_uv=False)
        angle = float(np.degrees(np.arccos(np.clip(cosines.min(), -1.0, 1.0))))
        if angle > VARIES_DEG and common_motion > VARIES_GAIN * max(own_motion, np.finfo(float).tiny):
            if worst is None or angle > worst[0]:
                worst = (angle, label)
    if worst is None:
        return []
    return [warning("constraint_varies",
                    f"{stage}: the constraint of {worst[1]} alone lies {worst[0]:.3g}° from the common one "
                    f"and fits its motion > {VARIES_GAIN:g}× better: the constraint changes over the data "
                    "(learn-a method: auto, or per_demo: true, fits one per stretch)")]


def not_identifiable(stage: str, data: Demonstrations, Y: np.ndarray,
                     noise_var: np.ndarray | None = None) -> list[dict[str, str]]:
    """``not_identifiable`` when the training targets ``Y`` (N, q) of a policy never move along
    some direction (rank r < q beyond their noise): π cannot be learnt along it — a constant
    constraint hides it — so π's predictions there are the basis' extrapolation (the
    constrained motion N π does not depend on them). Names the hidden direction."""
    q = Y.shape[1]
    if noise_var is None:
        lv = noise_levels(data)
        noise_var = lv["u_noise"] if lv["temporal"] and len(lv["u_noise"]) == q else np.zeros(q)
    r = action_rank(Y, noise_var)
    if r >= q or r == 0:
        return []
    hidden, _ = _null_rows(Y, q - r)
    v = hidden[0] * np.sign(hidden[0][np.argmax(np.abs(hidden[0]))])
    words = " + ".join(f"{c:.2f}·{n}" for c, n in zip(v, data.action_names, strict=True) if abs(c) >= 0.05)
    return [warning("not_identifiable",
                    f"{stage}: the training targets span {r} of {q} directions: π is not identifiable along "
                    f"{q - r} direction(s) ({words}{', …' if q - r > 1 else ''}); its predictions there are "
                    "extrapolation, the constrained motion N π is not affected")]


def status(checks: list[dict[str, str]]) -> str:
    """``poor`` when a verdict check fired, ``unjudged`` when the stage has no metric to be
    judged by (``not_judged``), else ``ok``."""
    if any(c["code"] in VERDICT_CODES for c in checks):
        return "poor"
    return "unjudged" if any(c["code"] == "not_judged" for c in checks) else "ok"


#: Why a policy learnt alone on data without ground truth has no metric, and how to get one.
NO_POLICY_METRIC = ("the data has no true π (NUPE) and no constraint was learnt to compare Ñπ̃ with the "
                    "observations (NCPE_obs); learn one before it (ccl run with stages: [learn-a, learn-pi]) "
                    "or evaluate the policy on data with ground truth")


def not_judged(stage: str, what: str) -> list[dict[str, str]]:
    """``not_judged``: the stage has no metric at all, so nothing supports its result (its status
    is ``unjudged``); ``what`` says why and what would give one."""
    return [warning("not_judged", f"{stage}: no metric to judge it by: {what}")]


#: The checks that make a stage ``poor``.
VERDICT_CODES = ("overfit", "no_better_than_baseline", "constraint_does_not_hold", "far_from_truth",
                 "no_heldout_support", "degenerate_input")


# -- honest by construction (issue 30 item 5) -----------------------------------------------------
def far_from_truth(stage: str, comparison: dict[str, Any] | None) -> list[dict[str, str]]:
    """``far_from_truth`` when the learnt constraint is far from the ground truth the file
    carries (:func:`ccl_cli.app.truth.compare`: k differs, or the median angle is too large)."""
    if not comparison or not comparison["far"]:
        return []
    return [warning("far_from_truth", f"{stage}: {comparison['why']}")]


def nullspace_far_from_truth(stage: str, part: str, metrics: dict[str, Any] | None) -> list[dict[str, str]]:
    """``far_from_truth`` when the file carries the true null-space part w and the learnt w̃ is
    no closer to it, on ``part``, than w̃ = 0: NUPE_w (``metrics``' entry, eq. of ALGORITHMS.md's
    metric table, normalised by w's variance) not below :data:`ZERO_LEVEL` by at least its
    standard error. The NPE alone cannot say this: it measures how consistent w̃ is with u along
    w̃'s own direction, and a w̃ far from the truth can be consistent."""
    found = (metrics or {}).get("NUPE_w")
    if not found or not np.isfinite(found["value"]):
        return []
    if found["value"] + (found.get("se") or 0.0) < ZERO_LEVEL:
        return []
    where = "held-out" if part == "test" else "training"
    return [warning("far_from_truth", f"{stage}: {where} NUPE_w {found['value']:.3g} against the file's true "
                                      f"null-space part w is no better than w̃ = 0 ({ZERO_LEVEL:g})")]


def heldout_support(selection: dict[str, Any] | None, evidence: dict[str, Any] | None,
                    part: str) -> dict[str, Any] | None:
    """Whether held-out evidence supports the k > 0 rows learn-a's ``auto`` chose: the states'
    geometry (a model of rank k within its limit on held-out demonstrations or blocks), or the
    velocity candidates (the winner's held-out rank at least k), or else the rows holding on the
    held-out ``part`` (``evidence``: :func:`constraint_evidence`). {supported, why}; None when
    there is nothing to support (k = 0, or a method other than ``auto``, judged by its test data)."""
    from ccl_cli.learn.constraint.sure import judged

    selection = selection or {}
    k = int(selection.get("n_constraints") or 0)
    if selection.get("rule") != "auto" or k == 0:
        return None
    if selection.get("decided_by") == "states":
        holding = [m for m in (selection.get("geometry") or {}).get("models") or []
                   if m["k"] == k and m["holds"]]
        if holding:
            best = min(holding, key=lambda m: max(m["drift"]))
            return {"supported": True, "why": f"the states' geometry: {best['basis']} "
                    f"({best['scope'].replace('_', ' ')}), {best['measure']} {max(best['drift']):.3g} ≤ "
                    f"{best['limit']:g}{judged(best['measure'])}"}
    held = (selection.get("forces") or {}).get("heldout") if selection.get("decided_by") == "forces" else None
    if held:  # contact stretches from the forces: their rows fitted without blocks held out inside them
        return {"supported": bool(held["supported"]), "why": f"the forces' contact stretches: {held['why']}"}
    winner = next((r for r in selection.get("candidates") or [] if r.get("chosen") and r["class"] != "none"),
                  None)
    if winner is not None and (winner.get("k") or 0) >= k:
        return {"supported": True, "why": f"{winner['class']}: held-out rank {winner['k']} "
                f"({winner.get('folds')}; {winner.get('rank_reason') or 'the noise rule'})"}
    if evidence is not None and evidence.get("holds"):
        return {"supported": True, "why": f"its rows hold on the {part} data"}
    said = ("not cross-validated" if not selection.get("candidates") else
            f"the held-out rank of {winner['class']} is {winner.get('k')}" if winner is not None else
            "no candidate was chosen on held-out data")
    return {"supported": False, "why": f"no held-out evidence supports {k} row(s) ({said})"}


def no_heldout_support(stage: str, support: dict[str, Any] | None) -> list[dict[str, str]]:
    """``no_heldout_support`` when :func:`heldout_support` found none."""
    if support is None or support["supported"]:
        return []
    return [warning("no_heldout_support", f"{stage}: {support['why']}")]


def model_parameters(model: Any) -> int | None:
    """How many numbers a fitted constraint model learnt: k(q − k) per constant set of k rows
    (one per window, demonstration or stretch), the size of its weights for a model of A(x);
    None when not known."""
    model = getattr(model, "chosen_", model)
    by_demo = model.models_by_demonstration()
    if by_demo is not None:
        counts = [model_parameters(m) for m in by_demo.values()]
        return None if any(c is None for c in counts) else int(sum(counts))
    for name in ("weights_", "W_"):
        value = getattr(model, name, None)
        if value is not None:
            return int(sum(np.size(w) for w in value) if isinstance(value, list) else np.size(value))
    A = getattr(model, "A_", None)
    if A is not None and np.ndim(A) >= 2:
        k, q = np.shape(A)[-2:]
        return int(np.prod(np.shape(A)[:-2], dtype=int) * k * (q - k))
    return None


def degenerate_input(stage: str, data: Demonstrations, Y: np.ndarray, on: str, model: Any,
                     u_var: float | None = None, share: float = 1e-3) -> list[dict[str, str]]:
    """``degenerate_input`` when a constraint was learnt from input that cannot show one: a
    recording at rest (:func:`motion`: ``no_motion``), a learnt w̃ (``on`` "w") whose variance is
    below ``share`` of u's (``u_var``), or fewer samples than the model has parameters."""
    why = []
    if any(w["code"] == "no_motion" for w in motion(data)):
        why.append("the recording does not move (its actions are at their noise level)")
    if on == "w" and u_var:
        ratio = float(np.var(Y, axis=0).sum()) / u_var
        if not ratio >= share:
            why.append(f"the learnt w̃ it was learnt from holds {ratio:.2g} of u's variance (< {share:g})")
    n_params = model_parameters(model)
    if n_params is not None and data.n_samples < n_params:
        why.append(f"{data.n_samples} training samples for {n_params} parameters")
    if not why:
        return []
    return [warning("degenerate_input", f"{stage}: learnt from degenerate input: {'; '.join(why)}")]
