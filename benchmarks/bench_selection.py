"""ccl's model selection against scikit-learn's where they do the same job (issue 27): should a
splitter or the search be scikit-learn's? One JSON object per line:

* {"measure": "folds", "n", "demos", "ccl_s", "sklearn_s", "ratio", "same"}: five folds by
  demonstration of n samples — ``make_folds`` against ``GroupKFold(5).split`` (each the best of
  ``--repeats``); ``same``: whether the two hold out the same samples in each fold, up to the order
  of the folds (GroupKFold balances fold sizes, make_folds permutes demonstrations by its seed, so
  they need not).
* {"measure": "search", "learner", "n", "candidates", "ccl_s", "ccl_fits", "sklearn_s",
  "sklearn_fits", "ratio", "ccl_best", "sklearn_best"}: the learner's own default grid searched
  by demonstration folds — ``Tuned`` (budgeted, early stop, shared work) against
  ``GridSearchCV(cv=GroupKFold(3))`` with metadata routing passing the demonstration ids; fits
  counted (candidates × folds, + the refit), and the parameters each chose.

``ratio`` = sklearn / ccl: above 1, ours is faster. Both sides run in the same process, one after
the other, so a neighbour's load shows in both.

Run:  python benchmarks/bench_selection.py [--n 200000] [--repeats 5]
"""

from __future__ import annotations

import argparse
import json
import sys
import time
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parents[1]))

import sklearn  # noqa: E402
from sklearn.model_selection import GridSearchCV, GroupKFold  # noqa: E402

from ccl_cli import simulate as sim  # noqa: E402
from ccl_cli.learn.model_selection import Tuned, make_folds  # noqa: E402
from ccl_cli.learn.nullspace import NullSpaceComponent  # noqa: E402
from ccl_cli.learn.policy import PolicyLearner  # noqa: E402


def best_of(fn, repeats: int) -> tuple[float, object]:
    times, out = [], None
    for _ in range(repeats):
        t0 = time.perf_counter()
        out = fn()
        times.append(time.perf_counter() - t0)
    return min(times), out


def folds(n: int, demos: int, repeats: int) -> dict:
    groups = np.repeat(np.arange(demos), n // demos)
    X = np.zeros((len(groups), 1))
    ours_s, ours = best_of(lambda: make_folds(groups, len(groups), 5, 0).pairs, repeats)
    theirs_s, theirs = best_of(lambda: list(GroupKFold(5).split(X, groups=groups)), repeats)
    held = sorted(tuple(np.unique(groups[test])) for _, test in ours)
    same = held == sorted(tuple(np.unique(groups[test])) for _, test in theirs)
    return {"measure": "folds", "n": len(groups), "demos": demos, "ccl_s": ours_s, "sklearn_s": theirs_s,
            "ratio": theirs_s / ours_s, "same": same}


def search(name: str, make, data) -> dict:
    grid = make(tune=True)._tune_grid(data.X, data.U)
    n_cand = int(np.prod([len(v) for v in grid.values()]))
    t0 = time.perf_counter()
    ours = Tuned(make(tune=False), grid, folds=3, budget=10_000).fit(data.X, data.U, groups=data.demo)
    ours_s = time.perf_counter() - t0
    with sklearn.config_context(enable_metadata_routing=True):
        t0 = time.perf_counter()
        theirs = GridSearchCV(make(tune=False), grid, cv=GroupKFold(3)).fit(data.X, data.U, groups=data.demo)
        theirs_s = time.perf_counter() - t0
    return {"measure": "search", "learner": name, "n": data.n_samples, "candidates": n_cand, "ccl_s": ours_s,
            "ccl_fits": ours.tuning_["budget_used"], "sklearn_s": theirs_s, "sklearn_fits": 3 * n_cand + 1,
            "ratio": theirs_s / ours_s, "ccl_best": ours.best_params_, "sklearn_best": theirs.best_params_}


def main() -> None:
    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=200_000)
    ap.add_argument("--repeats", type=int, default=5)
    args = ap.parse_args()
    print(json.dumps(folds(args.n, 100, args.repeats)), flush=True)
    toy = sim.toy2d(constraint="parabola", seed=0, n_demos=100)
    ncl = sim.toy2d(task=True, n_demos=100, seed=0)
    for name, make, data in (("policy pi", lambda **k: PolicyLearner(method="pi", **k), toy),
                             ("ncl", lambda **k: NullSpaceComponent(**k), ncl)):
        print(json.dumps(search(name, make, data), default=str), flush=True)


if __name__ == "__main__":
    main()
