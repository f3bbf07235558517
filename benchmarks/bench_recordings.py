"""Realistic recordings (issue 17): what the product does on them, how well the fault detectors
find what was injected, and which rule chooses the number of constraints right — including
"no constraint".

    python benchmarks/bench_recordings.py [--seeds 10] [--pipeline-seeds 1] [--realism-seeds 3]
                                          [--only faults,rank,pipeline,realism] [--cases PREFIX,...]

JSON lines on stdout (one per case and seed, then one summary per case), the tables on
stderr at the end. Sections:

* ``faults`` — ccl_cli/io/faults.py on ``tracker_flips`` with every fault injected (0.2–2 mm,
  50 and 200 Hz): injected vs found per kind; false positives on clean recordings (tracker
  plane/bowl 0–2 mm at 50–1000 Hz, jittery stamps, the arm wipe, reaches, 2-D strokes, a
  drawing around the transmitter); nhat's normal (k = 1) before and after the repair.
* ``rank`` — per scenario and seed, the k chosen by today's rules (``ratio``, ``threshold``,
  ``eigengap``) and by the noise-aware rule (ccl_cli/learn/constraint/noise_rank.py), with
  the evidence it reads (energy / noise variance and share of the motion of the true
  constraint rows and of the first free row), from which MARGIN and SHARE are chosen.
* ``pipeline`` — the product as a user runs it, on ``ccl simulate`` files: ``ccl learn-a
  FILE`` and ``ccl run`` with ``stages: [learn-v, learn-a, learn-pi]``, default options:
  status, chosen k, the angle of the learnt normal to the truth, held-out NPOE and NPPE,
  learn-pi's held-out NCPE_obs, warnings.
* ``realism`` — what real logs add (issue 30: compliance along the rows, tremor, drift, filtered
  velocities) on hinges, slides, surfaces worked in phases and free motion: ``ccl simulate NAME
  [--set ...]`` then ``ccl learn-a FILE`` with its defaults, the learnt rows at every sample as
  ``ccl predict`` gives them against the true ones stored in the file: k against the truth's,
  the median and 90th percentile over the constrained samples of the largest principal angle
  (a sample whose learnt rank differs counts as 90°), the share of free samples (approach,
  retract) left free, status and what learn-a chose.
"""

from __future__ import annotations

import argparse
import contextlib
import io
import json
import sys
import tempfile
import time
from collections import Counter, defaultdict
from collections.abc import Callable
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))
sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "tests"))

from learnt import largest_angles, learn_a, true_rows  # noqa: E402

from ccl_cli import simulate as sim  # noqa: E402
from ccl_cli.cli import main as ccl  # noqa: E402
from ccl_cli.dataset import Demonstrations  # noqa: E402
from ccl_cli.io import faults  # noqa: E402
from ccl_cli.learn.constraint import (  # noqa: E402
    KnownFeatureConstraint,
    StateDependentConstraint,
    StateIndependentConstraint,
    rank,
)
from ccl_cli.learn.constraint import noise_rank as nr  # noqa: E402
from ccl_cli.simulate.recordings import TRACKER_ORIGIN, derive  # noqa: E402

NOISES_MM = (0.2, 0.5, 1.0, 2.0)
RULES = ("ratio", "threshold", "eigengap", "noise")
TABLES: dict[str, list[str]] = defaultdict(list)


def emit(row: dict) -> None:
    print(json.dumps(row, default=float), flush=True)


def angle_deg(a: np.ndarray, b: np.ndarray) -> float:
    """Angle between the lines of unit vectors a and b (0–90°)."""
    c = abs(float(np.dot(a, b)) / (np.linalg.norm(a) * np.linalg.norm(b)))
    return float(np.degrees(np.arccos(min(c, 1.0))))


def normal_angle(rows: np.ndarray, normal: np.ndarray) -> float | None:
    """Angle (°) between a true normal (q,) and the span of learnt rows (k, q); None for k = 0."""
    rows = np.atleast_2d(np.asarray(rows, float))
    if rows.size == 0:
        return None
    q, _ = np.linalg.qr(rows.T)
    n = normal / np.linalg.norm(normal)
    return float(np.degrees(np.arccos(min(np.linalg.norm(q.T @ n), 1.0))))


# -- faults ----------------------------------------------------------------------------------
def _nhat_normal(U: np.ndarray) -> np.ndarray:
    return StateIndependentConstraint(n_constraints=1).fit(None, U).A_[0]


def faults_section(seeds: range) -> None:
    kinds = Counter()
    hits = Counter()
    angles: dict[str, list[float]] = defaultdict(list)
    stamp_faults = ("repeat", "duplicate", "skip", "step", "back")
    for rate in (50.0, 200.0):
        for noise in (0.2, 1.0, 2.0):
            for seed in seeds:
                d = sim.tracker_flips(n_spikes=3, stamp_faults=stamp_faults, noise=noise * 1e-3, rate=rate,
                                      duration=60.0, seed=seed)
                t0 = time.perf_counter()
                c = faults.clean_positions(d.t, d.X, d.demo)
                seconds = time.perf_counter() - t0
                truth = {f["kind"]: f["ranges"] for f in d.metadata["faults"]}
                found = {f["kind"]: f["ranges"] for f in c.report(d.t)}
                row = {"section": "faults", "case": "tracker_flips", "rate_hz": rate, "noise_mm": noise,
                       "seed": seed, "seconds": round(seconds, 4)}
                for kind, ranges in truth.items():
                    got = found.get(kind, [])
                    if kind == "clock_step":  # at rest (or slow) a clock step is reported as a gap
                        as_gap = [r for r in found.get("gap", []) if r in ranges]
                        kinds[(rate, "clock_step reported as gap")] += 0
                        hits[(rate, "clock_step reported as gap")] += len(as_gap)
                        got = got + as_gap
                    hit = sum(r in got for r in ranges)
                    kinds[(rate, kind)] += len(ranges)
                    hits[(rate, kind)] += hit
                    row[kind] = f"{hit}/{len(ranges)}"
                extra = {k: len(v) for k, v in found.items() if k not in truth}
                row["unexpected"] = extra
                normal = d.truth["A"][0]
                U_fixed, _ = derive(c.t, c.X, c.demo, rate)
                row["nhat_raw_deg"] = angle_deg(_nhat_normal(d.U), normal)
                row["nhat_repaired_deg"] = angle_deg(_nhat_normal(U_fixed), normal)
                angles["raw"].append(row["nhat_raw_deg"])
                angles["repaired"].append(row["nhat_repaired_deg"])
                emit(row)
    for (rate, kind), n in sorted(kinds.items()):
        TABLES["faults: injected → found (tracker_flips, 0.2/1/2 mm)"].append(
            f"{rate:6.0f} Hz  {kind:26s} {hits[(rate, kind)]:4d}" + (f" / {n}" if n else ""))
    for key, vals in angles.items():
        v = np.asarray(vals)
        TABLES["faults: nhat normal vs truth (deg)"].append(
            f"{key:9s} median {np.median(v):6.2f}  max {v.max():6.2f}  > 5°: {(v > 5).sum()}/{len(v)}")
    clean_section(seeds)


def _clean_cases(seed: int) -> list[tuple[str, Demonstrations]]:
    cases = []
    for noise in (0.0, 0.2, 1.0, 2.0):
        for rate in (50.0, 200.0, 1000.0):
            cases.append((f"plane {noise} mm {rate:g} Hz",
                          sim.tracker_plane(noise=noise * 1e-3, rate=rate, duration=30.0, seed=seed)))
        cases.append((f"bowl {noise} mm 50 Hz",
                      sim.tracker_sphere(noise=noise * 1e-3, duration=30.0, seed=seed)))
    cases.append(("plane 1 mm, 3 ms jitter", sim.tracker_plane(jitter=3e-3, duration=30.0, seed=seed)))
    cases.append(("around the transmitter", sim.tracker_flips(n_flips=0, offset=tuple(-TRACKER_ORIGIN),
                                                              duration=30.0, seed=seed)))
    cases.append(("arm_wipe 200 Hz", sim.arm_wipe(n_demos=3, seed=seed)))
    cases.append(("arm_wipe_joint 1 kHz", sim.arm_wipe_joint(n_demos=2, rate=1000.0, seed=seed)))
    cases.append(("free_reach", sim.free_reach(seed=seed)))
    cases.append(("flow2d", sim.flow2d(seed=seed)))
    return cases


def clean_section(seeds: range) -> None:
    false = Counter()
    tried = Counter()
    for seed in seeds[:3]:
        for name, d in _clean_cases(seed):
            c = faults.clean_positions(d.t, d.X, d.demo)
            sp_u = faults.spikes(d.U, d.t, d.demo)
            found = {f.kind: f.count for f in c.findings}
            if sp_u:
                found["spike (actions)"] = sp_u.count
            tried[name] += 1
            false[name] += sum(found.values())
            emit({"section": "faults", "case": f"clean: {name}", "seed": seed, "found": found,
                  "spike_max_z": faults.spikes(d.X, d.t, d.demo).detail.get("max_z")})
    for name in tried:
        TABLES["faults: findings on clean recordings (should be 0)"].append(
            f"{name:28s} {false[name]} in {tried[name]} recordings")


# -- rank ------------------------------------------------------------------------------------
def nhat_rules(d: Demonstrations, derivative: dict | None) -> tuple[dict[str, int], nr.RowEvidence]:
    q = d.n_action
    out = {r: StateIndependentConstraint(selection=r).fit(d.X, d.U, d.demo).n_constraints_
           for r in ("ratio", "threshold", "eigengap")}
    _, vecs = np.linalg.eigh(d.U.T @ d.U)
    ev = nr.row_evidence(d.U, vecs.T[: q - 1], d.demo, d.t, d.X, derivative)
    chosen = nr.noise_rank(ev, q - 1)
    out["noise"] = chosen.n_constraints if chosen is not None else out["ratio"]
    return out, ev


def angular_rules(make: Callable[..., object], d: Demonstrations, derivative: dict | None, m: int
                  ) -> tuple[dict[str, int], nr.RowEvidence]:
    """threshold / eigengap / ratio from one fit of all m rows (nmse per row, as alpha and
    lambda apply them), the noise rule on the same rows."""
    model = make(n_constraints=m).fit(d.X, d.U, d.demo)
    nmse = np.asarray(model.nmse_)
    k = 1
    while k < len(nmse) and not (nmse[k] > nmse[:k].min() and nmse[k] > 1e-3):
        k += 1
    out = {"threshold": k, "eigengap": rank.gap(np.append(nmse, 1.0)).n_constraints,
           "ratio": rank.ratio(nmse, m).n_constraints}
    ev = nr.row_evidence(d.U, model.constraint(d.X), d.demo, d.t, d.X, derivative)
    chosen = nr.noise_rank(ev, m)
    out["noise"] = chosen.n_constraints if chosen is not None else out["ratio"]
    return out, ev


def alpha(d, derivative):
    return angular_rules(lambda **kw: StateDependentConstraint(tune=False, n_restarts=1, **kw), d, derivative,
                         d.n_action - 1)


def lam(features, m):
    def make(**kw):
        return KnownFeatureConstraint(features=features, tune=False, n_restarts=1, **kw)
    return lambda d, derivative: angular_rules(make, d, derivative, m)


def nhat(d, derivative):
    return nhat_rules(d, derivative)


def windows(d: Demonstrations, seconds: float) -> Demonstrations:
    """One demonstration per ``seconds`` window of a recording."""
    out = d.subset(np.arange(d.n_samples))
    out.demo = (d.t // seconds).astype(np.int64)
    return out


def repaired(d: Demonstrations) -> Demonstrations:
    c = faults.clean_positions(d.t, d.X, d.demo)
    U, deriv = derive(c.t, c.X, c.demo, d.metadata["rate_hz"])
    return Demonstrations(X=c.X, U=U, demo=c.demo, t=c.t, metadata={**d.metadata, "derivative": deriv})


def _derivative(d: Demonstrations) -> dict | None:
    return d.derivative


#: (case, true k, make(seed) → dataset, learner(d, derivative), per_demo)
def rank_cases(quick: bool) -> list[tuple[str, int | None, Callable, Callable, bool]]:
    dur = 30.0 if quick else 60.0
    cases: list = []
    for noise in NOISES_MM:
        cases.append((f"tracker_plane {noise} mm", 1,
                      lambda s, n=noise: sim.tracker_plane(noise=n * 1e-3, duration=dur, seed=s),
                      nhat, False))
    for noise in NOISES_MM:
        cases.append((f"tracker_sphere {noise} mm (alpha)", 1,
                      lambda s, n=noise: sim.tracker_sphere(noise=n * 1e-3, duration=dur, seed=s),
                      alpha, False))
    cases += [
        ("tracker_plane 0.2 mm, wobble 1 mm", 1,
         lambda s: sim.tracker_plane(noise=2e-4, wobble=1e-3, duration=dur, seed=s), nhat, False),
        ("tracker_plane 500 Hz 1 mm", 1, lambda s: sim.tracker_plane(rate=500.0, duration=dur, seed=s),
         nhat, False),
        ("toy2d fixed", 1, lambda s: sim.toy2d(seed=s), nhat, False),
        ("toy2d parabola (alpha)", 1, lambda s: sim.toy2d(constraint="parabola", seed=s), alpha, False),
        ("two_link (lambda)", 1, lambda s: sim.two_link(seed=s), lam("arm2", 1), False),
        ("arm7 1 row", 1, lambda s: sim.arm7(rows=(0,), seed=s), nhat, False),
        ("arm7 2 rows", 2, lambda s: sim.arm7(rows=(0, 1), seed=s), nhat, False),
        ("arm7 jacobian 2 rows (lambda)", 2, lambda s: sim.arm7(rows=(0, 1), constraint="jacobian", seed=s),
         lam({"arm": "arm7", "rows": [0, 1, 2]}, 2), False),
        ("varying_constraint (per demo)", 1, lambda s: sim.varying_constraint(seed=s), nhat, True),
        ("varying_constraint 30 dB (per demo)", 1, lambda s: sim.varying_constraint(snr_db=30.0, seed=s),
         nhat, True),
        ("tracker_flips raw", 1, lambda s: sim.tracker_flips(duration=dur, seed=s), nhat, False),
        ("tracker_flips repaired", 1, lambda s: repaired(sim.tracker_flips(duration=dur, seed=s)),
         nhat, False),
        ("tracker_tilt whole", 1, lambda s: sim.tracker_tilt(seed=s), nhat, False),
        ("tracker_tilt 6-s windows", 1, lambda s: windows(sim.tracker_tilt(seed=s), 6.0), nhat, True),
        ("arm_wipe wipe phase", 1, lambda s: sim.phase_subset(sim.arm_wipe(n_demos=4, seed=s), "wipe"),
         nhat, False),
        ("arm_wipe whole (mixed)", None, lambda s: sim.arm_wipe(n_demos=4, seed=s), nhat, False),
        ("arm_wipe_joint wipe phase (lambda)", 1,
         lambda s: sim.phase_subset(sim.arm_wipe_joint(n_demos=4, seed=s), "wipe"),
         lam({"arm": "arm7", "rows": [0, 1, 2]}, 2), False),
        ("free_reach", 0, lambda s: sim.free_reach(seed=s), nhat, False),
        ("free_reach 1 mm", 0, lambda s: sim.free_reach(noise=1e-3, seed=s), nhat, False),
        ("flow2d", 0, lambda s: sim.flow2d(seed=s), nhat, False),
    ]
    return cases


def _evidence_points(truth: int, ev: nr.RowEvidence) -> list[tuple[str, float, float]]:
    """(class, r, share) of the rows the rule must judge: the true constraint rows and the
    first free row; rows after the first with r relative to max(r_1, 1), as the rule reads them."""
    r, f = ev.ratio, ev.share
    first = max(float(r[0]), 1.0)
    out = [("constraint row 1" if j == 0 else "constraint row k≥2", float(r[j] if j == 0 else r[j] / first),
            float(f[j])) for j in range(truth)]
    if truth < len(r):
        out.append(("free row 1" if truth == 0 else "free row k≥2",
                    float(r[truth] if truth == 0 else r[truth] / first), float(f[truth])))
    return out


def rank_section(seeds: range, quick: bool, only: list[str]) -> None:
    points: list[tuple[str, float, float]] = []
    for case, truth, make, learner, per_demo in rank_cases(quick):
        if only and not any(case.startswith(o) for o in only):
            continue
        chosen: dict[str, list[int]] = defaultdict(list)
        case_points: list[tuple[str, float, float]] = []
        t0 = time.perf_counter()
        for seed in seeds:
            d = make(seed)
            parts = [d.select_demos([i]) for i in d.demo_ids] if per_demo else [d]
            for part in parts:
                ks, ev = learner(part, _derivative(d))
                for r in RULES:
                    chosen[r].append(int(ks[r]))
                if truth is not None:
                    case_points += _evidence_points(truth, ev)
                emit({"section": "rank", "case": case, "seed": seed, "true_k": truth, "chosen": ks,
                      "energy_over_noise": ev.ratio.round(3).tolist(), "share": ev.share.tolist(),
                      "snr": ev.snr})
        right = {r: (sum(k == truth for k in chosen[r]) if truth is not None else None) for r in RULES}
        n = len(chosen["ratio"])
        emit({"section": "rank", "case": case, "summary": True, "true_k": truth, "runs": n, "right": right,
              "chosen": {r: dict(sorted(Counter(chosen[r]).items())) for r in RULES},
              "seconds": round(time.perf_counter() - t0, 1)})
        cells = "  ".join(f"{right[r]}/{n}".rjust(9) if truth is not None else str(dict(Counter(chosen[r])))
                          for r in RULES)
        TABLES["rank: runs with the true k (" + ", ".join(RULES) + ")"].append(
            f"{case:40s} k={truth!s:4s} {cells}")
        TABLES["rank: evidence per case (r = e/σ², further rows r/max(r_1, 1); f = share)"].append(
            f"{case:40s} " + "; ".join(_summary(case_points, cls) for cls in (
                "constraint row 1", "constraint row k≥2", "free row 1", "free row k≥2")
                if any(p[0] == cls for p in case_points)))
        if "raw" not in case and "windows" not in case:  # faulty data; windows that explore one direction
            points += case_points
    if points:
        tab = TABLES["rank: evidence for MARGIN, RATIO, SHARE (all cases but raw faults and windows)"]
        for cls in ("constraint row 1", "constraint row k≥2", "free row 1", "free row k≥2"):
            tab.append(f"{cls:20s} {_summary(points, cls)}")
        tab.append(f"(MARGIN = {nr.MARGIN:g}, RATIO = {nr.RATIO:g}, SHARE = {nr.SHARE:g}; a constraint row "
                   "needs r ≤ MARGIN (row 1) or ≤ RATIO (further rows), or f ≤ SHARE)")


def _summary(points: list[tuple[str, float, float]], cls: str) -> str:
    """Constraint rows: the largest r among those the share does not catch (f > SHARE) and the
    largest f among those r does not catch; free rows: the smallest r and f."""
    p = np.array([(r, f) for c, r, f in points if c == cls])
    if not len(p):
        return f"{cls}: –"
    if cls.startswith("constraint"):
        limit = nr.MARGIN if cls.endswith("1") else nr.RATIO
        by_r, by_f = p[p[:, 1] > nr.SHARE, 0], p[p[:, 0] > limit, 1]
        return (f"{cls}: max r {p[:, 0].max():.3g} (where f > SHARE: "
                f"{by_r.max() if len(by_r) else float('nan'):.3g}), max f where r > limit "
                f"{by_f.max() if len(by_f) else float('nan'):.3g}, n={len(p)}")
    return f"{cls}: min r {p[:, 0].min():.3g}, min f {p[:, 1].min():.3g}, n={len(p)}"


# -- pipeline --------------------------------------------------------------------------------
def _run(argv: list[str]) -> tuple[int, dict]:
    buf = io.StringIO()
    with contextlib.redirect_stdout(buf), contextlib.redirect_stderr(io.StringIO()):  # warnings: in the JSON
        code = ccl(argv)
    try:
        return code, json.loads(buf.getvalue())
    except json.JSONDecodeError:
        return code, {}


#: (case, ccl simulate arguments, the same simulation in Python (for its truth), true normal(d) or None)
def pipeline_cases() -> list[tuple[str, list[str], Callable, Callable | None]]:
    def plane_normal(d):
        return d.truth["A"][0]

    def mean_normal(d):
        return np.mean(d.truth_per_sample("A")[:, 0], 0)

    def wipe_normal(d):
        return np.asarray(d.metadata["normal"])

    return [
        ("tracker_flips", ["--duration", "60"], lambda s: sim.tracker_flips(duration=60.0, seed=s),
         plane_normal),
        ("tracker_tilt", [], lambda s: sim.tracker_tilt(seed=s), mean_normal),
        ("arm_wipe", ["--n-demos", "5", "--rate", "100"],
         lambda s: sim.arm_wipe(n_demos=5, rate=100.0, seed=s), wipe_normal),
        ("arm_wipe_joint", ["--n-demos", "5", "--rate", "100"],
         lambda s: sim.arm_wipe_joint(n_demos=5, rate=100.0, seed=s), None),
        ("free_reach", [], lambda s: sim.free_reach(seed=s), None),
        ("flow2d", [], lambda s: sim.flow2d(seed=s), None),
    ]


def _stage_row(out: Path, stage: str, summary: dict, normal_of: Callable | None, d: Demonstrations) -> dict:
    st = summary.get("stages", {}).get(stage, {})
    row = {"status": summary.get("status"), "k": st.get("n_constraints"),
           "test_NPOE": st.get("test", {}).get("NPOE"), "test_NPPE": st.get("test", {}).get("NPPE"),
           "warnings": sorted({w["code"] for w in summary.get("warnings", [])})}
    metrics = out / "metrics.json"
    if metrics.exists():
        m = json.loads(metrics.read_text()).get(stage, {})
        row["on"] = m.get("on")
        rows = (m.get("constraint") or {}).get("rows")
        if normal_of is not None and rows is not None:
            row["angle_deg"] = normal_angle(np.asarray(rows), normal_of(d))
    return row


def pipeline_section(seeds: range) -> None:
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        for case, args, make, normal_of in pipeline_cases():
            for seed in seeds:
                f = tmpdir / f"{case}_{seed}.h5"
                code, _ = _run(["simulate", case, "-o", str(f), "--seed", str(seed), "-q", *args])
                if code:
                    emit({"section": "pipeline", "case": case, "seed": seed,
                          "error": f"simulate exit {code}"})
                    continue
                d = make(seed)
                t0 = time.perf_counter()
                code, res = _run(["learn-a", str(f), "-o", str(tmpdir / f"a_{case}_{seed}"), "--json", "-q"])
                learn_a = _stage_row(tmpdir / f"a_{case}_{seed}", "learn-a", res, normal_of, d)
                learn_a["seconds"] = round(time.perf_counter() - t0, 1)
                cfg = tmpdir / f"pipe_{case}_{seed}.yaml"
                cfg.write_text(f"data:\n  files: [{f}]\nstages: [learn-v, learn-a, learn-pi]\n")
                t0 = time.perf_counter()
                code, res = _run(["run", str(cfg), "-o", str(tmpdir / f"r_{case}_{seed}"), "--json", "-q"])
                run = _stage_row(tmpdir / f"r_{case}_{seed}", "learn-a", res, normal_of, d)
                pi = res.get("stages", {}).get("learn-pi", {})
                run["learn_pi_test_NCPE_obs"] = pi.get("test", {}).get("NCPE_obs")
                run["seconds"] = round(time.perf_counter() - t0, 1)
                emit({"section": "pipeline", "case": case, "seed": seed, "learn_a": learn_a, "run": run})
                TABLES["pipeline (today's defaults): k, angle°, test NPOE, status, warnings"].append(
                    f"{case:15s} s={seed}  learn-a: k={learn_a['k']} {_fmt(learn_a.get('angle_deg'))}° "
                    f"NPOE {_fmt(learn_a['test_NPOE'])} {learn_a['status']} {','.join(learn_a['warnings'])}"
                    f" | run (on {run.get('on')}): k={run['k']} {_fmt(run.get('angle_deg'))}° "
                    f"NPOE {_fmt(run['test_NPOE'])} pi NCPE_obs {_fmt(run['learn_pi_test_NCPE_obs'])} "
                    f"{run['status']} {','.join(run['warnings'])}")


# -- realism -----------------------------------------------------------------------------------
#: (case, ccl simulate problem, its --set / option arguments): the defaults of each simulation, then
#: one effect pushed to the largest of the real logs (docs/recordings.md).
REALISM_CASES: list[tuple[str, str, list[str]]] = [
    ("hinge", "hinge", []),
    ("hinge 4 demos", "hinge", ["--n-demos", "4"]),
    ("hinge 10 Hz", "hinge", ["--rate", "10"]),
    ("hinge grasp ±3 cm", "hinge", ["--set", "grasp=0.03"]),
    ("hinge compliance 6 mm", "hinge", ["--set", "compliance=0.006"]),
    ("hinge tremor 0.5 mm", "hinge", ["--set", "tremor=0.0005"]),
    ("hinge drift 0.5 mm/s", "hinge", ["--set", "drift=0.0005"]),
    ("hinge filtered velocities", "hinge", ["--set", "velocities=filtered"]),
    ("slide", "slide", []),
    ("slide bow 25 mm", "slide", ["--set", "bow=0.025"]),
    ("slide compliance 4 mm", "slide", ["--set", "compliance=0.004"]),
    ("slide drift 0.5 mm/s", "slide", ["--set", "drift=0.0005"]),
    ("slide filtered velocities", "slide", ["--set", "velocities=filtered"]),
    ("contact_phases plane", "contact_phases", []),
    ("contact_phases sphere", "contact_phases", ["--set", "surface=sphere"]),
    ("contact_phases compliance 4 mm", "contact_phases", ["--set", "compliance=0.004"]),
    ("contact_phases drift 0.2 mm/s", "contact_phases", ["--set", "drift=0.0002"]),
    ("contact_phases filtered velocities", "contact_phases", ["--set", "velocities=filtered"]),
    ("reach_goal", "reach_goal", []),
    ("reach_goal filtered velocities", "reach_goal", ["--set", "velocities=filtered"]),
    ("handwriting", "handwriting", []),
    ("handwriting 200 Hz", "handwriting", ["--rate", "200"]),
]


def realism_run(f: Path, out: Path) -> dict:
    """learn-a's defaults on one simulated file against its truth (module docstring)."""
    t0 = time.perf_counter()
    got = learn_a([f], out)
    row = {"exit": got.code, "k": got.k, "status": got.status, "seconds": round(time.perf_counter() - t0, 1)}
    if got.code:
        return row
    truth = true_rows(got.data)
    true_k = np.array([len(r) for r in truth])
    angles = largest_angles(got.rows, truth)
    held = true_k > 0
    learnt_k = np.array([len(r) for r in got.rows])
    learnt_free = learnt_k == 0
    found = held & (learnt_k == true_k)
    row.update(true_k=int(true_k.max()), chose=got.chose,
               angle_median=float(np.median(angles[held])) if held.any() else None,
               angle_p90=float(np.percentile(angles[held], 90)) if held.any() else None,
               found=float(found.sum() / held.sum()) if held.any() else None,
               angle_where_found=float(np.median(angles[found])) if found.any() else None,
               free_left_free=float(learnt_free[~held].mean()) if (~held).any() and held.any() else None,
               test_NPPE=(got.summary["stages"]["learn-a"].get("test") or {}).get("NPPE"),
               warnings=sorted({w["code"] for w in got.summary.get("warnings", [])}))
    return row


def realism_section(seeds: range, only: list[str]) -> None:
    title = ("realism (learn-a defaults vs truth): k right, k chosen, angle° (median over constrained "
             "samples, worst seed), free samples left free (worst), where the rows are found (contact: "
             "share of the constrained samples with the true rank, angle there), status, chosen")
    with tempfile.TemporaryDirectory() as tmp:
        tmpdir = Path(tmp)
        for n, (case, problem, args) in enumerate(REALISM_CASES):
            if only and not any(case.startswith(o) for o in only):
                continue
            runs = []
            for seed in seeds:
                f = tmpdir / f"{problem}_{n}_{seed}.h5"
                code, _ = _run(["simulate", problem, "-o", str(f), "--seed", str(seed), "-q", *args])
                if code:
                    emit({"section": "realism", "case": case, "seed": seed, "error": f"simulate exit {code}"})
                    continue
                row = {"section": "realism", "case": case, "seed": seed,
                       **realism_run(f, tmpdir / f"a_{f.stem}")}
                emit(row)
                runs.append(row)
            ok = [r for r in runs if r["exit"] == 0]
            right = [r for r in ok if r["k"] == r["true_k"]]
            angles = [r["angle_median"] for r in right if r["angle_median"] is not None]
            free = [r["free_left_free"] for r in ok if r.get("free_left_free") is not None]
            found = [(r["found"], r["angle_where_found"]) for r in right if r.get("found") is not None]
            ks = dict(sorted(Counter(r["k"] for r in ok).items()))
            emit({"section": "realism", "case": case, "summary": True, "runs": len(runs),
                  "right_k": len(right), "k": ks, "angle_median_max": max(angles) if angles else None})
            TABLES[title].append(
                f"{case:36s} truth k={ok[0]['true_k'] if ok else '?'}  {len(right)}/{len(runs)}  k={ks}"
                f"  angle {_fmt(max(angles)) if angles else '–':>6s}"
                + (f"  free {min(free):.2f}" if free else "")
                + (f"  rows found in {min(f for f, _ in found):.2f}–{max(f for f, _ in found):.2f} of the "
                   f"constrained samples, {_fmt(max((a for _, a in found if a is not None), default=None))}° "
                   "there" if found and min(f for f, _ in found) < 0.99 else "")
                + f"  {dict(Counter(r['status'] for r in ok))}  {sorted({r['chose'] for r in ok})}")


def _fmt(v) -> str:
    if v is None:
        return "–"
    return f"{v:.3g}"


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=10)
    ap.add_argument("--pipeline-seeds", type=int, default=1)
    ap.add_argument("--realism-seeds", type=int, default=3)
    ap.add_argument("--only", default="faults,rank,pipeline,realism",
                    help="sections (faults, rank, pipeline, realism)")
    ap.add_argument("--cases", default="", help="rank, realism: comma-separated case prefixes")
    ap.add_argument("--quick", action="store_true", help="30-s tracker recordings in the rank section")
    args = ap.parse_args()
    sections = args.only.split(",")
    t0 = time.perf_counter()
    if "faults" in sections:
        faults_section(range(args.seeds))
    if "rank" in sections:
        rank_section(range(args.seeds), args.quick, [c for c in args.cases.split(",") if c])
    if "pipeline" in sections:
        pipeline_section(range(args.pipeline_seeds))
    if "realism" in sections:
        realism_section(range(args.realism_seeds), [c for c in args.cases.split(",") if c])
    for title, lines in TABLES.items():
        print(f"\n## {title}", file=sys.stderr)
        for line in lines:
            print(line, file=sys.stderr)
    print(f"\n{time.perf_counter() - t0:.0f} s", file=sys.stderr)


if __name__ == "__main__":
    main()
