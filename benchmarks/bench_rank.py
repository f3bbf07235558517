"""Which rule chooses the number of constraints right? (issue 9, ALGORITHMS.md §3.4)

    python benchmarks/bench_rank.py [--seeds 20] [--quick]

JSON lines on stdout: one per (case, noise, rule) with the count of seeds where the rule
chose the true s, the counts chosen, and for the default rule on the tracker problems the
test NPOE on held-out time blocks (the reported split of a single recording). Rules:

* threshold — the original library's rule (nhat: nmse_k < 0.1; alpha: stop when nmse rises
  above the best and 1e-3), eigengap — largest ratio of consecutive residuals,
* ratio — the noise-aware threshold (residual ≤ 2× that of row 1), the default,
* cv — held-out NPOE, one-standard-error rule (nhat everywhere; alpha on --cv-seeds seeds).

Cases: the 7-DoF arm (s = 2, nhat), the 2-D toys (s = 1: fixed row with nhat, parabola with
alpha), the 2-link arm (s = 1, lambda), the tracker plane (s = 1, nhat) and sphere (s = 1,
alpha) at position noise 0.2, 0.5, 1, 2 mm, plus harder tracker variants (uneven in-plane
motion ``spread``, sensor ``wobble`` off the surface) reported for information.
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from collections import Counter
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent))

from ccl_cli import simulate as sim  # noqa: E402
from ccl_cli.learn import model_selection as S  # noqa: E402
from ccl_cli.learn.consistency import npoe_error  # noqa: E402
from ccl_cli.learn.constraint import (  # noqa: E402
    KnownFeatureConstraint,
    StateDependentConstraint,
    StateIndependentConstraint,
    rank,  # noqa: E402
)

NOISES_MM = (0.2, 0.5, 1.0, 2.0)




def nhat_counts(data, max_k: int | None = None, cv: bool = True) -> dict[str, int]:
    U = data.U
    q = U.shape[1]
    max_k = max_k or q - 1
    out = {}
    for rule in ("threshold", "eigengap", "ratio") + (("cv",) if cv else ()):
        out[rule] = StateIndependentConstraint(selection=rule).fit(data.X, U, groups=data.demo).n_constraints_
    return out


def alpha_counts(data, cv: bool, **kw) -> dict[str, int]:
    """threshold/eigengap/ratio from one fit of every row (nmse per row); cv separately."""
    q = data.U.shape[1]
    full = StateDependentConstraint(n_constraints=q - 1, **kw).fit(data.X, data.U)
    nmse = np.asarray(full.nmse_)
    k = 1
    while k < len(nmse) and not (nmse[k] > nmse[:k].min() and nmse[k] > 1e-3):
        k += 1
    out = {"threshold": k, "eigengap": rank.gap(np.append(nmse, 1.0)).n_constraints,
           "ratio": rank.ratio(nmse, q - 1).n_constraints}
    if cv:
        out["cv"] = StateDependentConstraint(selection="cv", **kw).fit(data.X, data.U,
                                                                         groups=data.demo).n_constraints_
    return out


def held_out_npoe(data, make) -> tuple[float, int]:
    """Test NPOE on held-out time blocks (the pipeline's split of a single recording)."""
    hold = S.holdout_split(data.demo, 0.3, seed=0, gap=9)
    tr, te = data.subset(hold.train), data.subset(hold.test)
    model = make().fit(tr.X, tr.U, groups=tr.demo)
    return npoe_error(model.projection(te.X), te.U), int(model.n_constraints_)


def npoe_stats(values: list[float]) -> dict[str, float]:
    return {"test_npoe_blocks_median": float(np.median(values)),
            "test_npoe_blocks_max": float(np.max(values)),
            "test_npoe_blocks_below_0.03": int(np.sum(np.asarray(values) < 0.03))}


def emit(rows: list[dict], case: str, noise, truth: int, extra: dict | None = None) -> None:
    rules = sorted({r for row in rows for r in row})
    for rule in rules:
        ks = [row[rule] for row in rows if rule in row]
        line = {"case": case, "noise_mm": noise, "rule": rule, "true_s": truth,
                "right": int(sum(k == truth for k in ks)), "seeds": len(ks),
                "chosen": dict(sorted(Counter(int(k) for k in ks).items()))}
        if extra and rule == rank.DEFAULT_RULE:
            line.update(extra)
        print(json.dumps(line), flush=True)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=20)
    ap.add_argument("--cv-seeds", type=int, default=3, help="seeds for alpha's (slow) cv rule")
    ap.add_argument("--quick", action="store_true", help="shorter tracker recordings (30 s)")
    ap.add_argument("--only", default="", help="comma-separated case prefixes")
    args = ap.parse_args()
    seeds = range(args.seeds)
    duration = 30.0 if args.quick else 90.0
    only = [s for s in args.only.split(",") if s]

    def wanted(case: str) -> bool:
        return not only or any(case.startswith(o) for o in only)

    t0 = time.perf_counter()
    if wanted("arm7"):
        emit([nhat_counts(sim.arm7(rows=(0, 1), seed=s)) for s in seeds],
             "arm7 nhat", 10.0, 2)
        emit([nhat_counts(sim.arm7(rows=(0, 1, 2), seed=s)) for s in seeds], "arm7 rows 0-2 nhat", 10.0, 3)
    if wanted("toy"):
        emit([nhat_counts(sim.toy2d(seed=s)) for s in seeds], "toy2d fixed nhat", 10.0, 1)
        emit([alpha_counts(sim.toy2d(constraint="parabola", seed=s), cv=False, n_restarts=1)
              for s in seeds[:5]], "toy2d parabola alpha", 10.0, 1)
    if wanted("two_link"):
        rows = []
        for s in seeds[:5]:
            d = sim.two_link(seed=s)
            rows.append({r: KnownFeatureConstraint(features="arm2", selection=r).fit(d.X, d.U, groups=d.demo)
                         .n_constraints_ for r in ("threshold", "eigengap", "ratio")})
        emit(rows, "two_link lambda", 0.0, 1)
    if wanted("plane"):
        for noise in NOISES_MM:
            datas = [sim.tracker_plane(noise=noise * 1e-3, seed=s, duration=duration) for s in seeds]
            npoe = [held_out_npoe(d, StateIndependentConstraint)[0] for d in datas]
            emit([nhat_counts(d) for d in datas], "tracker_plane nhat", noise, 1, npoe_stats(npoe))
        for kw in ({"spread": 0.3}, {"wobble": 1e-3}, {"spread": 0.3, "wobble": 1e-3}):
            for noise in (0.2, 2.0):
                rows = [nhat_counts(sim.tracker_plane(noise=noise * 1e-3, seed=s, duration=duration, **kw))
                        for s in seeds]
                emit(rows, f"tracker_plane nhat {kw}", noise, 1)
    if wanted("sphere"):
        for noise in NOISES_MM:
            rows, npoe = [], []
            for s in seeds:
                d = sim.tracker_sphere(noise=noise * 1e-3, seed=s, duration=duration)
                rows.append(alpha_counts(d, cv=s < args.cv_seeds))
                if noise == 1.0:
                    npoe.append(held_out_npoe(d, StateDependentConstraint)[0])
            emit(rows, "tracker_sphere alpha", noise, 1, npoe_stats(npoe) if npoe else None)
    print(json.dumps({"total_seconds": round(time.perf_counter() - t0, 1)}))


if __name__ == "__main__":
    main()
