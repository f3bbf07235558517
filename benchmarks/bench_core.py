"""Scaling benchmark of the learning core (issues 10 and 19). One JSON object per line:

    {"learner", "path", "problem", "N", "K", "K_default", "seconds", "cpu_seconds", "peak_mb",
     "mem_ratio", "test_error", "metric", "floor_seconds", "floor_ratio", "floor_default_ratio",
     "chosen", ...}

* ``path`` — ``default``: the learner as a user gets it (``Learner()`` with its defaults,
  tuning on where the learner tunes); ``untuned``: the same with ``tune=False`` (its fixed
  default basis); ``tutorial``: the policy learners with the 10×10 grid of RBFs, σ² = 0.5
  (explicit, so not tuned) that earlier versions of this benchmark timed.
* ``seconds`` / ``cpu_seconds`` — wall and process CPU time of ``fit`` (one run; compare
  ratios, the VM is shared and noisy);
* ``peak_mb`` / ``mem_ratio`` — peak memory traced by tracemalloc during a second ``fit``
  (with ``--memory``) and its ratio to the input arrays (X, U and, for pi-coupled, the
  projections);
* ``test_error`` — on 10,000 held-out samples from the same simulator (another seed); with
  ``--error-seeds S`` also ``test_error_median`` / ``test_error_seeds`` over S training draws;
* ``floor_seconds`` — the one-pass floor, in the same process and under the same conditions:
  forming the fitted model's normal equations once (features of every sample with the basis
  the model ended with and the Gram matrix of its regressor rows, in 8192-row chunks), best of
  3; ``floor_ratio`` = fit CPU seconds / floor CPU seconds. ``floor_default_ratio`` divides
  by the floor of the learner's configured default basis instead (the same unless tuning chose
  another basis).
* ``--scaling`` adds ``error_at_tenth`` and ``error_ratio_vs_tenth``: the median test error over
  3 training draws at N against the same at N/10 (the bar: ≤ 2).

Run:  python benchmarks/bench_core.py [--quick] [--only NAME[,NAME]] [--sizes 1e4,1e5]
      [--paths default,untuned] [--memory] [--error-seeds 3] [--scaling]
(single-threaded BLAS is forced, as on one core of the 2-core VM).
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import argparse  # noqa: E402
import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402
import tracemalloc  # noqa: E402
from collections.abc import Callable  # noqa: E402
from types import SimpleNamespace  # noqa: E402

import numpy as np  # noqa: E402

from ccl_cli import simulate as sim  # noqa: E402
from ccl_cli.learn.constraint import (  # noqa: E402
    KnownFeatureConstraint,
    LinearConstraint,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.nullspace import NullSpaceComponent  # noqa: E402
from ccl_cli.learn.policy import PolicyLearner  # noqa: E402
from ccl_cli.metrics import nppe, nupe  # noqa: E402

CHUNK = 8192
N_TEST = 10_000
POLICY_K = 100
TUTORIAL_BASIS = {"kind": "rbf", "n_centres": POLICY_K, "centres": "grid", "sigma2": 0.5}
POLICIES = ("pi", "pi-weighted", "pi-coupled", "lwpi", "dpl")
PATHS = ("default", "untuned", "tutorial")


def emit(**row) -> None:
    print(json.dumps(row), flush=True)


def timed(fn: Callable[[], object]) -> tuple[float, float, object]:
    """(wall seconds, process CPU seconds, result) of one call."""
    t, c = time.perf_counter(), time.process_time()
    out = fn()
    return time.perf_counter() - t, time.process_time() - c, out


def traced_peak(fn: Callable[[], object]) -> float:
    """Peak bytes traced by tracemalloc during one call."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    fn()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return float(peak)


def gram_floor(rows: Callable[[slice], np.ndarray], n: int) -> tuple[float, float]:
    """(wall, CPU) seconds to form Σ_n h_n h_nᵀ once, rows h built chunk by chunk by ``rows(slice)``."""

    def once() -> None:
        G = None
        for start in range(0, n, CHUNK):
            H = rows(slice(start, min(start + CHUNK, n)))
            G = H.T @ H if G is None else G + H.T @ H

    wall, cpu, _ = timed(once)
    return wall, cpu


def kron_rows(B: np.ndarray, m: int) -> np.ndarray:
    """Jacobian-shaped rows g ⊗ β with g = 1: (c, K) → (c, m K)."""
    return np.repeat(B[:, None, :], m, axis=1).reshape(len(B), -1)


# -- problems: (train, test) demonstrations of size n -------------------------------------
def toy(n: int, seed: int = 0, **kw):
    """Uniform toy2d samples; the first n train, the next N_TEST test (one constraint)."""
    data = sim.toy2d(sampling="uniform", n_samples=n + N_TEST, n_demos=1, seed=seed, **kw)
    return data.subset(np.arange(n)), data.subset(np.arange(n, n + N_TEST))


def arm(n: int, seed: int):
    return sim.two_link(n_demos=max(1, n // 40), n_steps=40, seed=seed)


def policy_problem(n: int, seed: int):
    return sim.varying_constraint(n_demos=max(1, n // 100), noise=0.01, seed=seed)


def floor_rows_of(learner: str, tr) -> Callable[[object, slice], np.ndarray]:
    """The regressor rows of ``learner``'s normal equations for a fitted model and a row slice."""
    X, U = tr.X, tr.U
    if learner == "nhat":
        return lambda m, s: U[s]
    if learner == "linear":
        return lambda m, s: m._stack(X[s], U[s])
    if learner == "alpha":
        return lambda m, s: kron_rows(m.basis_.transform(X[s]), 1)
    if learner == "lambda":
        def rows(m, s):
            np.einsum("nrq,nq->nr", m.features_(X[s]), U[s])
            return kron_rows(m.basis_.transform(X[s]), 1)
        return rows
    if learner == "dpl":
        return lambda m, s: m.basis_.transform(X[s])
    if learner == "lwpi":
        def rows(m, s):
            B = m.basis_.transform(X[s])
            phi = np.hstack([X[s], np.ones((len(B), 1))])
            R = (phi[:, :, None] * U[s][:, None, :]).reshape(len(B), -1)
            RR = (R[:, :, None] * R[:, None, :]).reshape(len(B), -1)
            return np.sqrt(np.abs(B.T @ RR))  # the (K, D²) accumulation, then a tiny Gram
        return rows
    return lambda m, s: kron_rows(m.basis_.transform(X[s]), U.shape[1])  # ncl, pi, pi-weighted, pi-coupled


def make(learner: str, path: str, seed: int = 0) -> Callable[..., object]:
    """An unfitted learner of ``learner`` on ``path`` (None: the path does not apply)."""
    tune = {} if path == "default" else {"tune": False}
    if learner == "nhat":
        return None if path != "default" else StateIndependentConstraint(seed=seed)
    if learner == "linear":
        return None if path != "default" else LinearConstraint(seed=seed)
    if learner == "alpha":
        return StateDependentConstraint(seed=seed, **tune) if path != "tutorial" else None
    if learner == "lambda":
        return KnownFeatureConstraint(features="arm2", seed=seed, **tune) if path != "tutorial" else None
    if learner == "ncl":
        return NullSpaceComponent(seed=seed, **tune) if path != "tutorial" else None
    if path == "tutorial":
        return PolicyLearner(method=learner, basis=TUTORIAL_BASIS, seed=seed)
    return PolicyLearner(method=learner, seed=seed, **tune)


def problem_of(learner: str, n: int, seed: int) -> SimpleNamespace:
    """Training data of size n drawn with ``seed``, the test data (a fixed seed for the
    simulators, the next N_TEST samples for the toys), the inputs' bytes, the metric."""
    if learner in ("nhat", "linear", "alpha", "ncl"):
        kw = {"nhat": {"constraint": "fixed"}, "linear": {"constraint": "parabola"},
              "alpha": {"constraint": "parabola"}, "ncl": {"constraint": "fixed", "task": True}}[learner]
        tr, te = toy(n, seed, **kw)
        problem = {"nhat": "toy2d fixed uniform", "linear": "toy2d parabola uniform, polynomial 1",
                   "alpha": "toy2d parabola uniform", "ncl": "toy2d fixed + task"}[learner]
        metric = "test NUPE(w)" if learner == "ncl" else "test NPPE"
    elif learner == "lambda":
        tr, te = arm(n, seed), arm(N_TEST, 1000)
        problem, metric = "two_link", "test NPPE"
    else:
        tr, te = policy_problem(n, seed), policy_problem(N_TEST, 1000)
        problem, metric = "varying_constraint noise 0.01", "test NUPE"
    P = tr.true_projection() if learner == "pi-coupled" else None
    inputs = tr.X.nbytes + tr.U.nbytes + (P.nbytes if P is not None else 0)
    return SimpleNamespace(tr=tr, te=te, P=P, inputs=inputs, problem=problem, metric=metric)


def fit(model, c: SimpleNamespace):
    kw = {} if c.P is None else {"projections": c.P}
    return model.fit(c.tr.X, c.tr.U, groups=c.tr.demo, **kw)


def test_error(learner: str, model, te) -> float:
    if learner == "ncl":
        return nupe(te.truth["w"], model.predict(te.X)).value
    if learner in ("nhat", "linear", "alpha", "lambda"):
        return nppe(te.true_projection(), model.projection(te.X), te.truth["pi"], te.U).value
    return nupe(te.truth["pi"], model.predict(te.X)).value


def median_error(learner: str, path: str, n: int, seeds: int) -> tuple[float, list[float]]:
    errs = []
    for seed in range(seeds):
        c = problem_of(learner, n, seed)
        errs.append(test_error(learner, fit(make(learner, path, seed), c), c.te))
    return float(np.median(errs)), errs


def floor_of(learner: str, c: SimpleNamespace, model) -> tuple[float, float]:
    rows = floor_rows_of(learner, c.tr)
    best = min((gram_floor(lambda s: rows(model, s), c.tr.n_samples) for _ in range(3)), key=lambda f: f[1])
    return best


def n_features(model) -> int | None:
    basis = getattr(model, "basis_", None)
    return None if basis is None else int(basis.n_features)


def run(learner: str, path: str, n: int, memory: bool = False, error_seeds: int = 1,
        scaling: bool = False) -> None:
    c = problem_of(learner, n, 0)
    if make(learner, path) is None:
        return
    seconds, cpu, model = timed(lambda: fit(make(learner, path), c))
    err = test_error(learner, model, c.te)
    floor_wall, floor_cpu = floor_of(learner, c, model)
    ratio = cpu / floor_cpu
    extra: dict = {}
    if path == "default" and getattr(model, "tuning_", None):
        default = fit(make(learner, "untuned"), c) if learner not in ("nhat", "linear") else model
        _, d_cpu = floor_of(learner, c, default)
        extra["K_default"] = n_features(default)
        extra["floor_default_ratio"] = round(cpu / d_cpu, 1)
        tuning = model.tuning_
        extra["chosen"] = tuning.get("chosen")
        extra["budget_used"] = tuning.get("budget_used")
        extra["budget_unit"] = tuning.get("budget_unit")
    if memory:
        peak = traced_peak(lambda: fit(make(learner, path), c))
        extra.update(peak_mb=round(peak / 2**20, 2), mem_ratio=round(peak / c.inputs, 2))
    if error_seeds > 1:
        med, errs = median_error(learner, path, n, error_seeds)
        extra.update(test_error_median=float(f"{med:.4g}"),
                     test_error_seeds=[float(f"{e:.4g}") for e in errs])
    if scaling:
        med = extra.get("test_error_median") or median_error(learner, path, n, 3)[0]
        tenth = median_error(learner, path, max(n // 10, 100), 3)[0]
        extra.update(error_median=float(f"{med:.4g}"), error_at_tenth=float(f"{tenth:.4g}"),
                     error_ratio_vs_tenth=round(med / tenth, 2) if tenth > 0 else None)
    emit(learner=learner, path=path, problem=c.problem, N=c.tr.n_samples, K=n_features(model),
         seconds=round(seconds, 4), cpu_seconds=round(cpu, 4), test_error=float(f"{err:.4g}"),
         metric=c.metric, floor_seconds=round(floor_wall, 5), floor_cpu_seconds=round(floor_cpu, 5),
         floor_ratio=round(ratio, 1), **extra)


LEARNERS = ("nhat", "linear", *POLICIES, "ncl", "alpha", "lambda")
SIZES = (10_000, 100_000, 1_000_000)


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N = 1e4 only (smoke run)")
    ap.add_argument("--only", default="", help="comma-separated learners (e.g. ncl,alpha)")
    ap.add_argument("--sizes", default="", help="comma-separated N values (default 1e4,1e5,1e6)")
    ap.add_argument("--paths", default="default,untuned", help=f"comma-separated, of {', '.join(PATHS)}")
    ap.add_argument("--memory", action="store_true", help="also trace the peak memory of a second fit")
    ap.add_argument("--error-seeds", type=int, default=1,
                    help="also fit on this many training draws and report the median test error")
    ap.add_argument("--scaling", action="store_true",
                    help="median test error over 3 draws at N against N/10")
    args = ap.parse_args(argv)
    only = [x for x in args.only.split(",") if x] or list(LEARNERS)
    sizes = [int(float(s)) for s in args.sizes.split(",") if s] or list(SIZES)
    if args.quick:
        sizes = [10_000]
    paths = [p for p in args.paths.split(",") if p]
    for learner in only:
        for n in sizes:
            for path in paths:
                run(learner, path, n, args.memory, args.error_seeds, args.scaling)
    return 0


if __name__ == "__main__":
    sys.exit(main())
