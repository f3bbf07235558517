"""learn-a's ``auto`` (issue 17) on the simulated recordings: the chosen model class, the number
of constraints, the angle to the true constraint and the held-out NPOE, against today's default
(nhat with the ``ratio`` rule; lambda with the ``ratio`` rule on the arm's Jacobian constraint,
``lambda_jacobian``: the explicit method lambda with its new default rule, noise).

    python benchmarks/bench_auto.py [--seeds 20] [--only free_reach,flow2d,...] [--windows 2,3,4,6,8]

JSON lines on stdout (one per scenario and seed, then one summary per scenario), the tables on
stderr at the end. Library calls (AutoConstraint.fit with the data's times and derivative), as
``ccl learn-a`` runs them on the training part. ``--windows`` instead measures the per-window
candidate's window length: per-window held-out NPOE and the auto choice for each length.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from ccl_cli import simulate as sim  # noqa: E402
from ccl_cli.app.scoring import applied_on, projection_on  # noqa: E402
from ccl_cli.dataset import Demonstrations  # noqa: E402
from ccl_cli.learn import model_selection as S  # noqa: E402
from ccl_cli.learn.constraint import (  # noqa: E402
    AutoConstraint,
    KnownFeatureConstraint,
    StateIndependentConstraint,
)
from ccl_cli.metrics import subspace_angle  # noqa: E402

ARM7_JACOBIAN = {"arm": "arm7", "rows": [0, 1, 2]}


def emit(row: dict) -> None:
    print(json.dumps(row, default=float), flush=True)


#: name → (true k, make(seed), features of lambda or None, what to check)
SCENARIOS: dict[str, tuple[int, Callable[[int], Demonstrations], object, str]] = {
    "free_reach": (0, lambda s: sim.free_reach(seed=s), None, "k"),
    "flow2d": (0, lambda s: sim.flow2d(seed=s), None, "k"),
    "tracker_plane": (1, lambda s: sim.tracker_plane(duration=60.0, seed=s), None, "angle"),
    "wipe_phase": (1, lambda s: sim.phase_subset(sim.arm_wipe(n_demos=4, seed=s), "wipe"), None, "angle"),
    # whole recordings: approach (free), wipe (on the plane), retract (free)
    "wipe_whole": (1, lambda s: sim.arm_wipe(seed=s), None, "angle"),
    "wipe_whole_50hz": (1, lambda s: sim.arm_wipe(rate=50.0, seed=s), None, "angle"),
    "wipe_whole_1khz": (1, lambda s: sim.arm_wipe(rate=1000.0, seed=s), None, "angle"),
    "wipe_whole_bias": (1, lambda s: sim.arm_wipe(offset=0.01, drift=2e-4, seed=s), None, "angle"),
    "tracker_sphere": (1, lambda s: sim.tracker_sphere(duration=60.0, seed=s), None, "heldout"),
    "tracker_tilt": (1, lambda s: sim.tracker_tilt(seed=s), None, "heldout"),
    "tracker_tilt_steps": (1, lambda s: sim.tracker_tilt(mode="steps", seed=s), None, "heldout"),
    # steps every 5 s / 7 s: not aligned with the windows of 2, 3, 4 or 6 s (the window study)
    "tracker_tilt_steps5": (1, lambda s: sim.tracker_tilt(mode="steps", window_s=5.0, seed=s), None,
                            "heldout"),
    "tracker_tilt_steps7": (1, lambda s: sim.tracker_tilt(mode="steps", window_s=7.0, seed=s), None,
                            "heldout"),
    "arm7_2rows": (2, lambda s: sim.arm7(rows=(0, 1), seed=s), None, "N"),
    "arm7_jacobian": (2, lambda s: sim.arm7(rows=(0, 1), constraint="jacobian", seed=s), ARM7_JACOBIAN, "k"),
    # explicit method: lambda (its default rule, noise, against ratio), not auto
    "lambda_jacobian": (2, lambda s: sim.arm7(rows=(0, 1), constraint="jacobian", seed=s), ARM7_JACOBIAN,
                        "lambda"),
}


def true_rows(d: Demonstrations, i: int) -> np.ndarray:
    if "normal" in d.metadata:
        return np.atleast_2d(d.metadata["normal"])
    return np.atleast_2d(d.truth_per_sample("A")[i])


def mean_angle(model, d: Demonstrations) -> float | None:
    """Median over samples (every 25th) of the angle between the learnt rows and the true ones."""
    idx = np.arange(0, d.n_samples, 25)
    rows = model.constraint(d.X[idx], groups=d.demo[idx], t=d.t[idx])
    if rows.shape[1] == 0:
        return None
    held = np.abs(rows).sum((1, 2)) > 0  # a constraint in stretches: where it holds
    return float(np.median([subspace_angle(rows[j], true_rows(d, i)) for j, i in enumerate(idx) if held[j]]))


def true_share(d: Demonstrations) -> float | None:
    """Share of the samples in the wipe phase (arm_wipe recordings)."""
    if "phases" not in d.metadata:
        return None
    return float(sim.phase_subset(d, "wipe").n_samples / d.n_samples)


def before(d: Demonstrations, features) -> int:
    """Today's default: nhat with the ratio rule, or lambda's own default with features."""
    if features is not None:
        return int(KnownFeatureConstraint(features=features, selection="ratio").fit(d.X, d.U, groups=d.demo)
                   .n_constraints_)
    return int(StateIndependentConstraint().fit(d.X, d.U, groups=d.demo).n_constraints_)


def run_case(name: str, seed: int, window: float | None = None) -> dict:
    truth, make, features, check = SCENARIOS[name]
    d = make(seed)
    deriv = d.derivative if d.derivative.derived else False
    row: dict = {"case": name, "seed": seed, "true_k": truth}
    fit_on, test = d, None
    if check == "N":  # max|N − N_true| on held-out demonstrations
        hold = S.holdout_split(d.demo, 0.3, seed)
        fit_on, test = d.subset(hold.train), d.subset(hold.test)
    kw = {} if window is None else {"window": window}
    if check == "lambda":
        t0 = time.process_time()
        model = KnownFeatureConstraint(features=features).fit(d.X, d.U, groups=d.demo, t=d.t,
                                                              derivative=deriv)
        return {**row, "cpu_s": round(time.process_time() - t0, 2), "k": model.n_constraints_,
                "chosen": "lambda", "before_k": before(d, features)}
    t0 = time.process_time()
    model = AutoConstraint(features=features, **kw).fit(fit_on.X, fit_on.U, groups=fit_on.demo, t=fit_on.t,
                                                        derivative=deriv)
    row["cpu_s"] = round(time.process_time() - t0, 2)
    sel = model.selection_
    row.update(k=model.n_constraints_, chosen=sel["chosen"], before_k=before(fit_on, features))
    row["heldout_npoe"] = None if model.heldout_ is None else model.heldout_["mean"]
    cands = {c["class"]: c for c in sel["candidates"]}
    row["candidate_k"] = {c: v["k"] for c, v in cands.items() if v["k"] is not None}
    row["candidate_npoe"] = {c: v["heldout_error"] for c, v in cands.items()
                             if v["heldout_error"] is not None}
    if check in ("angle", "heldout") and model.n_constraints_:
        row["angle_deg"] = mean_angle(model, d)
    if "time_share" in cands.get("stretches", {}):
        row["stretches_heldout_share"] = cands["stretches"]["time_share"]
    if sel["chosen"] == "stretches":
        row["share"] = model.model_.share_
        row["true_share"] = true_share(d)
    if test is not None:  # as ccl scores a held-out part: a model per stretch is fitted on it (said so)
        applied = applied_on(model, test, test.U)
        N = projection_on(applied, test)
        row["refitted_on_test"] = applied.refitted
        row["max_abs_N_err"] = float(np.abs(N - test.true_projection()).max())
    return row


def passes(row: dict) -> bool:
    truth, _, _, check = SCENARIOS[row["case"]]
    if row["k"] != truth:
        return False
    if check == "angle":
        return row.get("angle_deg") is not None and row["angle_deg"] <= 1.5
    if check == "heldout":
        local = ("per_window", "per_segment", "alpha_linear", "alpha")
        return row["chosen"] in local and row["heldout_npoe"] < 0.03
    if check == "N":
        return row["max_abs_N_err"] <= 1e-2
    return True


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--only", default="", help="comma-separated scenarios")
    ap.add_argument("--windows", default="", help="comma-separated window lengths (s): the window study")
    args = ap.parse_args()
    names = [n for n in SCENARIOS if not args.only or n in args.only.split(",")]
    windows = [float(w) for w in args.windows.split(",") if w] or [None]
    tables: dict[str, list[str]] = defaultdict(list)
    for name in names:
        for window in windows:
            rows = []
            for seed in range(args.seeds):
                row = run_case(name, seed, window)
                row["window"] = window
                row["pass"] = passes(row)
                rows.append(row)
                emit(row)
            summary = {"case": name, "window": window, "summary": True, "runs": len(rows),
                       "pass": sum(r["pass"] for r in rows),
                       "k": dict(sorted(Counter(r["k"] for r in rows).items())),
                       "before_k": dict(sorted(Counter(r["before_k"] for r in rows).items())),
                       "chosen": dict(Counter(r["chosen"] for r in rows)),
                       "cpu_s_median": float(np.median([r["cpu_s"] for r in rows]))}
            for key in ("angle_deg", "heldout_npoe", "max_abs_N_err", "share",
                        "stretches_heldout_share"):
                vals = [r[key] for r in rows if r.get(key) is not None]
                if vals:
                    summary[key] = [float(np.min(vals)), float(np.median(vals)), float(np.max(vals))]
            pw = [r["candidate_npoe"]["per_window"] for r in rows
                  if "per_window" in r.get("candidate_npoe", {})]
            if pw:
                summary["per_window_npoe"] = [float(np.min(pw)), float(np.median(pw)), float(np.max(pw))]
            emit(summary)
            shown = ("angle_deg", "heldout_npoe", "max_abs_N_err", "per_window_npoe", "share",
                     "stretches_heldout_share")
            extra = "  ".join(f"{k} {v[0]:.3g}/{v[1]:.3g}/{v[2]:.3g}"
                              for k, v in summary.items() if k in shown)
            label = name if window is None else f"{name} W={window:g}s"
            title = "auto: runs passing the bar; k (after) vs today's default (before); min/median/max"
            tables[title].append(
                f"{label:24s} {summary['pass']:2d}/{len(rows)}  k {summary['k']}  "
                f"before {summary['before_k']}  chosen {summary['chosen']}  {extra}  "
                f"cpu {summary['cpu_s_median']:.1f} s")
    for title, lines in tables.items():
        print(f"\n## {title}", file=sys.stderr)
        for line in lines:
            print(line, file=sys.stderr)


if __name__ == "__main__":
    main()
