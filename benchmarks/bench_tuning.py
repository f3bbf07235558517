"""Tuned defaults vs the original tutorials' hand-tuned settings (issue 9).

    python benchmarks/bench_tuning.py [--seeds 5] [--only accuracy,angles,time,configs]

JSON lines on stdout:

* ``accuracy`` — per (problem, learner): the median over seeds of the test error (NUPE of
  π for policies, NUPE of w for ncl) with (a) the tutorial's hand-tuned settings
  (ALGORITHMS.md §7: a 10×10 grid of RBFs with σ² = 0.5 for pi, pi-weighted and lwpi;
  16 k-means RBFs for ncl on the toy, 100 on the 2-link arm with a task part), (b) the
  untuned defaults (``tune=False``), (c) the defaults (tuning on), and whether (c) ≤ (a).
  Tutorial data: 500 training + 500 test states uniform in [−1, 1]² (split by demonstration,
  50 groups), noise std 0.01, a new constraint per demonstration for π; the 2-link arm:
  40 demonstrations × 40 steps, 30 % of them held out.
* ``angles`` — alpha and lambda, tuned vs untuned (their fixed default bases), median over
  seeds of the test error: alpha on the parabola toy (test NPPE, 30 % of the demonstrations
  held out) and on the tracker bowl at 1 mm noise (NPOE on held-out time blocks), lambda on
  the two-link arm (test NPPE); with fit seconds and the chosen bases.
* ``time`` — fit seconds of every learner, tuned vs untuned, on its tutorial problem.
* ``configs`` — wall seconds of ``ccl run`` on every shipped config (tuning on).
* ``original`` — pi and lwpi with their defaults against the original library's hand-tuned
  settings on the original's own tutorial data (issue 17.7; :func:`original_table`): one row per
  problem (attractor, limit cycle and linear-map toys, the 2-link arm) × size × noise × learner,
  the median test NUPE over seeds and whether the default is ≤ the original's setting.
"""

from __future__ import annotations

import argparse
import json
import subprocess
import sys
import time
from collections.abc import Callable
from dataclasses import dataclass
from pathlib import Path

import numpy as np

ROOT = Path(__file__).resolve().parent.parent
sys.path.insert(0, str(ROOT))

from ccl_cli import simulate as sim  # noqa: E402
from ccl_cli.learn.constraint import (  # noqa: E402
    KnownFeatureConstraint,
    LinearConstraint,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.kinematics import TwoLinkArm  # noqa: E402
from ccl_cli.learn.linalg import nullspace_projection, unit_rows  # noqa: E402
from ccl_cli.learn.nullspace import NullSpaceComponent  # noqa: E402
from ccl_cli.learn.policy import PolicyLearner  # noqa: E402
from ccl_cli.metrics import nupe  # noqa: E402

TUTORIAL_PI = {"kind": "rbf", "n_centres": 100, "centres": "grid", "sigma2": 0.5}


def policy_data(policy: str, seed: int):
    return sim.toy2d(policy=policy, vary_constraint=True, sampling="uniform", n_samples=1000, seed=seed)


def ncl_data(seed: int):
    return sim.toy2d(policy="limit_cycle", task=True, sampling="uniform", n_samples=1000, seed=seed)


def compare(problem: str, learner: str, seeds: range, data, hand: dict, fit, truth: str) -> None:
    """One accuracy row: the median over seeds of the test NUPE (of ``truth``) with the
    hand-tuned settings ``hand``, the untuned defaults and the defaults. ``data(seed)`` →
    (train, test); ``fit(kw, seed, train)`` → a fitted model."""
    rows = []
    for seed in seeds:
        train, test = data(seed)
        rows.append([nupe(test.truth[truth], fit(kw, seed, train).predict(test.X)).value
                     for kw in (hand, {"tune": False}, {})])
    med = np.median(np.array(rows), axis=0)
    print(json.dumps({"bench": "accuracy", "problem": problem, "learner": learner,
                      "metric": f"test NUPE{'_w' if truth == 'w' else ''}", "tutorial": med[0],
                      "untuned_default": med[1], "default_tuned": med[2],
                      "meets_bar": bool(med[2] <= med[0]), "seeds": len(seeds)}), flush=True)


def accuracy(seeds: range) -> None:
    cases = [(p, m) for p in ("attractor", "limit_cycle") for m in ("pi", "pi-weighted")]
    cases.append(("limit_cycle", "lwpi"))
    for policy, method in cases:
        compare(f"toy2d {policy}", method, seeds,
                lambda seed, p=policy: policy_data(p, seed).split(0.5, seed),
                {"basis": TUTORIAL_PI, "tune": False},
                lambda kw, seed, tr, m=method: PolicyLearner(method=m, seed=seed, **kw).fit(
                    tr.X, tr.U, groups=tr.demo), "pi")

    def ncl(kw, seed, tr):
        return NullSpaceComponent(seed=seed, **kw).fit(tr.X, tr.U, groups=tr.demo)

    compare("toy2d ncl (limit cycle, task b ~ U(-1, 1))", "ncl", seeds,
            lambda seed: ncl_data(seed).split(0.5, seed), {"n_centres": 16, "tune": False}, ncl, "w")
    # the 2-link arm's hand-tuned ncl setting: 100 k-means RBFs
    compare("two_link ncl (task b ~ U(-1, 1) per demo)", "ncl", seeds,
            lambda seed: sim.two_link(task=True, seed=seed).split(0.3, seed),
            {"n_centres": 100, "tune": False}, ncl, "w")


def angles(seeds: range) -> None:
    from ccl_cli.learn import model_selection as S
    from ccl_cli.learn.consistency import npoe_error
    from ccl_cli.metrics import nppe

    def parabola(seed):
        train, test = sim.toy2d(constraint="parabola", seed=seed).split(0.3, seed)
        return train, test, lambda m: nppe(test.true_projection(), m.projection(test.X), test.truth["pi"],
                                           test.U).value

    def arm(seed):
        train, test = sim.two_link(seed=seed).split(0.3, seed)
        return train, test, lambda m: nppe(test.true_projection(), m.projection(test.X), test.truth["pi"],
                                           test.U).value

    def bowl(seed):
        data = sim.tracker_sphere(noise=1e-3, seed=seed)
        hold = S.holdout_split(data.demo, 0.3, seed=0, gap=9)
        train, test = data.subset(hold.train), data.subset(hold.test)
        return train, test, lambda m: npoe_error(m.projection(test.X), test.U)

    cases = [("alpha", "toy2d parabola", "test NPPE", parabola, StateDependentConstraint),
             ("alpha", "tracker bowl 1 mm", "test NPOE (held-out blocks)", bowl, StateDependentConstraint),
             ("lambda", "two_link", "test NPPE", arm,
              lambda **kw: KnownFeatureConstraint(features="arm2", **kw))]
    for learner, problem, metric, make_data, make in cases:
        err: dict[str, list] = {"untuned": [], "tuned": []}
        secs: dict[str, list] = {"untuned": [], "tuned": []}
        chosen = []
        for seed in seeds:
            train, _, score = make_data(seed)
            for tag, tune in (("untuned", False), ("tuned", True)):
                t0 = time.perf_counter()
                model = make(seed=seed, tune=tune).fit(train.X, train.U, groups=train.demo)
                secs[tag].append(time.perf_counter() - t0)
                err[tag].append(score(model))
            basis = (model.tuning_ or {}).get("chosen", {}).get("basis", {})
            chosen.append(f"{basis.get('n_centres')}{' wide' if 'sigma2' in basis else ''}")
        med = {k: float(np.median(v)) for k, v in err.items()}
        print(json.dumps({"bench": "angles", "learner": learner, "problem": problem, "metric": metric,
                          "untuned": med["untuned"], "tuned": med["tuned"],
                          "tuned_not_worse": bool(med["tuned"] <= med["untuned"]),
                          "seconds_untuned": round(float(np.median(secs["untuned"])), 3),
                          "seconds_tuned": round(float(np.median(secs["tuned"])), 3),
                          "chosen_centres": chosen, "seeds": len(seeds)}), flush=True)


def fit_times() -> None:
    pi_train = policy_data("limit_cycle", 0).split(0.5, 0)[0]
    ncl_train = ncl_data(0).split(0.5, 0)[0]
    parabola = sim.toy2d(constraint="parabola", seed=0)
    arm = sim.two_link(seed=0)
    learners = {
        **{f"policy {m}": (lambda tune, m=m: PolicyLearner(method=m, tune=tune), pi_train)
           for m in ("pi", "pi-weighted", "lwpi", "dpl")},
        "ncl": (lambda tune: NullSpaceComponent(tune=tune), ncl_train),
        "nhat": (lambda tune: StateIndependentConstraint(), sim.toy2d(seed=0)),
        "alpha": (lambda tune: StateDependentConstraint(tune=tune), parabola),
        "alpha (tracker bowl)": (lambda tune: StateDependentConstraint(tune=tune),
                                 sim.tracker_sphere(seed=0)),
        "lambda": (lambda tune: KnownFeatureConstraint(features="arm2", tune=tune), arm),
        "linear-rbf": (lambda tune: LinearConstraint(regressors="rbf", tune=tune), parabola),
    }
    for name, (make, data) in learners.items():
        secs = {}
        for tune in (False, True):
            t0 = time.perf_counter()
            model = make(tune).fit(data.X, data.U, groups=data.demo)  # one fit shape for every learner
            secs["tuned" if tune else "untuned"] = round(time.perf_counter() - t0, 3)
        tuning = getattr(model, "tuning_", None) or {}
        print(json.dumps({"bench": "time", "learner": name, "samples": data.n_samples, **secs,
                          "ratio": round(secs["tuned"] / max(secs["untuned"], 1e-9), 1),
                          "candidates": len(tuning.get("scores", [])), "skipped": tuning.get("skipped", 0)}),
              flush=True)


def configs(tmp: Path) -> None:
    ccl = [sys.executable, "-c", "from ccl_cli.cli import entry; entry()"]
    for cfg in sorted((ROOT / "configs").glob("*.yaml")):
        t0 = time.perf_counter()
        proc = subprocess.run([*ccl, "run", str(cfg), "-o", str(tmp / cfg.stem), "--force", "-q", "--json"],
                              capture_output=True, text=True, cwd=ROOT,
                              env={"PYTHONPATH": str(ROOT), "PATH": str(Path(sys.executable).parent)})
        wall = time.perf_counter() - t0
        stages = json.loads(proc.stdout)["stages"] if proc.returncode == 0 else proc.stderr[-300:]
        metrics = json.loads((tmp / cfg.stem / "metrics.json").read_text()) if proc.returncode == 0 else {}
        print(json.dumps({"bench": "configs", "config": cfg.name, "wall_seconds": round(wall, 2),
                          "under_10s": wall < 10,
                          "stage_seconds": {k: v.get("seconds") for k, v in metrics.items()},
                          "ok": proc.returncode == 0, "stages": stages}), flush=True)


# -- the original library's tutorials: its data recipe and its hand-tuned settings --------------
#: The original toy's "linear" policy: π(x) = [x; 1]ᵀ W.
ORIGINAL_LINEAR = np.array([[1.0, 2.0], [3.0, 4.0], [-1.0, 0.0]])


@dataclass
class PolicyData:
    """States X (N, p), the actions the learners see U (N, q), demonstration ids (N,) and the
    true unconstrained policy π (N, q)."""

    X: np.ndarray
    U: np.ndarray
    demo: np.ndarray
    pi: np.ndarray


def original_policy(name: str) -> Callable[[np.ndarray], np.ndarray]:
    """The toy tutorial's null-space policies, X (N, 2) → π (N, 2): the attractor 0.5 (0 − x),
    the limit cycle (radius 0.75, angular speed 1), the linear map [x; 1]ᵀ W."""
    if name == "linear":
        return lambda X: np.hstack([X, np.ones((len(X), 1))]) @ ORIGINAL_LINEAR
    return sim.toy_policy(name)


def random_rows(rng: np.random.Generator, n: int) -> np.ndarray:
    """n random constraint rows as the original draws them: unit vectors of U(0, 1)² (n, 2)."""
    return unit_rows(rng.uniform(0.0, 1.0, (n, 2)))


def original_toy(policy: str, n: int, noise: float, seed: int, n_demos: int = 50) -> PolicyData:
    """The toy tutorial's policy data: n states uniform in [−1, 1]², each with its own random
    constraint row, u = N π (+ noise of std ``noise``; the original fits the noise-free null-space
    component); the samples are dealt round robin into ``n_demos`` groups, the folds of a search."""
    rng = np.random.default_rng(seed)
    X = rng.uniform(-1.0, 1.0, (n, 2))
    pi = original_policy(policy)(X)
    W = np.einsum("nij,nj->ni", nullspace_projection(random_rows(rng, n)[:, None, :]), pi)
    return PolicyData(X, W + noise * rng.normal(size=W.shape), np.arange(n) % n_demos, pi)


def original_arm(n_traj: int, noise: float, seed: int, n_steps: int = 40, dt: float = 0.01) -> PolicyData:
    """The 2-link arm tutorial's policy data: ``n_traj`` trajectories from q = (0°, 90°) + U(0, 10°)
    per joint, π = q* − q with q* = (10°, −10°), A = r J(q) with a new random row r at every step,
    the state updated by dt · N π plus the original's state noise (std 0.01), a trajectory ended
    once ‖N π‖ < 1e-3; u = N π (+ noise of std ``noise``). Demonstration ids: the trajectories."""
    rng = np.random.default_rng(seed)
    arm = TwoLinkArm()
    target = np.deg2rad([10.0, -10.0])
    q = np.deg2rad(np.array([0.0, 90.0]) + rng.uniform(0.0, 10.0, (n_traj, 2)))
    live = np.ones(n_traj, bool)
    Xs, Ws, Ps, ids = [], [], [], []
    for _ in range(n_steps):  # over time steps; all trajectories at once
        pi = target - q
        A = np.einsum("nr,nrq->nq", random_rows(rng, n_traj), arm.jacobian(q))[:, None, :]
        w = np.einsum("nij,nj->ni", nullspace_projection(A), pi)
        live &= np.linalg.norm(w, axis=1) >= 1e-3
        Xs.append(q[live]), Ws.append(w[live]), Ps.append(pi[live]), ids.append(np.flatnonzero(live))
        q = q + dt * w + 0.01 * rng.normal(size=q.shape)
    demo = np.concatenate(ids)
    order = np.argsort(demo, kind="stable")
    X, W, pi = (np.concatenate(a)[order] for a in (Xs, Ws, Ps))
    return PolicyData(X, W + noise * rng.normal(size=W.shape), demo[order], pi)


#: The 10 × 10 grid of the toy tutorial over [−1.1, 1.1]².
TOY_GRID = np.stack([g.ravel() for g in np.meshgrid(*[np.linspace(-1.1, 1.1, 10)] * 2, indexing="ij")], 1)


def original_settings(problem: str, method: str) -> dict:
    """The original tutorials' hand-tuned settings of ``method`` (pi or lwpi) on ``problem``: the
    toys a 10 × 10 grid of RBFs with σ² = 0.5 (pi) or 0.005 (lwpi), the arm a 5 × 5 grid over the
    data with the default width; the original's absolute eigenvalue cut-off, no tuning."""
    if problem == "arm":
        basis = {"kind": "rbf", "n_centres": 25, "centres": "grid"}
    else:
        basis = {"kind": "rbf", "centres": TOY_GRID, "sigma2": 0.5 if method == "pi" else 0.005}
    return {"basis": basis, "cutoff_rule": "absolute", "tune": False}


#: Test NUPE below which both settings reproduce π to the rounding of float64 sums (a tie).
EXACT = 1e-20
#: (problem, sizes: toy samples or arm trajectories, the first the tutorial's)
ORIGINAL_PROBLEMS = [("attractor", (500, 2000, 10_000)), ("limit_cycle", (500, 2000, 10_000)),
                     ("linear", (500, 2000, 10_000)), ("arm", (40, 80, 250))]


def original_data(problem: str, size: int, noise: float, seed: int) -> tuple[PolicyData, PolicyData]:
    """(train, test) of one table row: the test set an independent draw of the tutorial's size."""
    if problem == "arm":
        return original_arm(size, noise, seed), original_arm(40, 0.0, seed + 10_000)
    return original_toy(problem, size, noise, seed), original_toy(problem, 500, 0.0, seed + 10_000)


def original_row(problem: str, size: int, noise: float, method: str, seeds: range) -> dict:
    """Median test NUPE over ``seeds`` of ``method`` with its defaults and with the original's
    settings; the bar: the default's ≤ the original's, or both below :data:`EXACT`."""
    errs: dict[str, list[float]] = {"default": [], "original": []}
    for seed in seeds:
        train, test = original_data(problem, size, noise, seed)
        for tag, kw in (("default", {}), ("original", original_settings(problem, method))):
            model = PolicyLearner(method=method, seed=seed, **kw).fit(train.X, train.U, groups=train.demo)
            errs[tag].append(nupe(test.pi, model.predict(test.X)).value)
    med = {k: float(np.median(v)) for k, v in errs.items()}
    exact = max(med.values()) < EXACT  # both reproduce π to rounding: a tie
    return {"bench": "original", "problem": problem, "size": size, "n_samples": len(train.X), "noise": noise,
            "learner": method, "default": med["default"], "original": med["original"],
            "ratio": med["default"] / med["original"] if med["original"] > 0 else float("nan"),
            "meets_bar": bool(med["default"] <= med["original"] or exact), "exact": bool(exact),
            "seeds": len(seeds)}


def original_table(seeds: range, noises: tuple[float, ...] = (0.0, 0.01)) -> list[dict]:
    """Every row: problems × sizes × noise levels × (pi, lwpi), printed as they come."""
    rows = []
    for problem, sizes in ORIGINAL_PROBLEMS:
        for size in sizes:
            for noise in noises:
                for method in ("pi", "lwpi"):
                    rows.append(original_row(problem, size, noise, method, seeds))
                    print(json.dumps(rows[-1]), flush=True)
    return rows


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--seeds", type=int, default=5)
    ap.add_argument("--only", default="accuracy,angles,time,configs,original")
    args = ap.parse_args()
    parts = set(args.only.split(","))
    if "accuracy" in parts:
        accuracy(range(args.seeds))
    if "angles" in parts:
        angles(range(args.seeds))
    if "time" in parts:
        fit_times()
    if "original" in parts:
        original_table(range(args.seeds))
    if "configs" in parts:
        import tempfile

        with tempfile.TemporaryDirectory() as tmp:
            configs(Path(tmp))


if __name__ == "__main__":
    main()
