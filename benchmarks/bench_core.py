"""Speed/accuracy benchmark of the learning core. One JSON object per line:
{"stage", "problem", "N", "q", "seconds", "metric", "value"}.

Run:  python benchmarks/bench_core.py   (single-threaded BLAS is forced for "one core")
"""

from __future__ import annotations

import os

os.environ.setdefault("OMP_NUM_THREADS", "1")
os.environ.setdefault("OPENBLAS_NUM_THREADS", "1")
os.environ.setdefault("MKL_NUM_THREADS", "1")

import json  # noqa: E402
import sys  # noqa: E402
import time  # noqa: E402

import numpy as np  # noqa: E402

from ccl_cli import simulate as sim  # noqa: E402
from ccl_cli.constraint import (  # noqa: E402
    KnownFeatureConstraint,
    LinearConstraint,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.linalg import unit_rows  # noqa: E402
from ccl_cli.metrics import nppe, nupe  # noqa: E402
from ccl_cli.nullspace import NullSpaceComponent  # noqa: E402
from ccl_cli.policy import PolicyLearner  # noqa: E402


def emit(stage: str, problem: str, n: int, q: int, seconds: float, metric: str, value: float) -> None:
    print(json.dumps({"stage": stage, "problem": problem, "N": n, "q": q,
                      "seconds": round(seconds, 4), "metric": metric, "value": value}), flush=True)


def timed(fn, repeats: int = 3):
    best, out = np.inf, None
    for _ in range(repeats):
        t = time.perf_counter()
        out = fn()
        best = min(best, time.perf_counter() - t)
    return best, out


def bench_nhat(n: int = 1_000_000, q: int = 7) -> None:
    rng = np.random.default_rng(0)
    A = np.linalg.qr(rng.normal(size=(q, 2)))[0].T  # 2 orthonormal rows
    pi = rng.normal(size=(n, q))
    U = pi - (pi @ A.T) @ A + rng.normal(scale=0.01, size=(n, q))
    seconds, model = timed(lambda: StateIndependentConstraint(selection="eigengap").fit(None, U))
    N_true = np.eye(q) - A.T @ A
    err = nppe(N_true, model.projection(np.zeros((1, 1)))[0], pi[:10000], U[:10000]).value
    emit("learn-a/nhat", "random rank-2", n, q, seconds, "NPPE", err)


def bench_alpha() -> None:
    vals, secs = [], []
    for seed in range(5):
        data = sim.toy2d(constraint="parabola", seed=seed)
        train, test = data.split(0.3, seed)
        s, model = timed(lambda tr=train: StateDependentConstraint().fit(tr.X, tr.U), repeats=1)
        secs.append(s)
        vals.append(nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U).value)
    emit("learn-a/alpha", "toy2d parabola 50x20 (median of 5 seeds)", train.n_samples, 2,
         float(np.median(secs)), "test NPPE", float(np.median(vals)))


def bench_lambda() -> None:
    data = sim.two_link(seed=0)
    train, test = data.split(0.3, 0)
    s, model = timed(lambda: KnownFeatureConstraint(features="arm2").fit(train.X, train.U), repeats=1)
    emit("learn-a/lambda", "two_link 40x40", train.n_samples, 2, s, "test NPPE",
         nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U).value)


def bench_linear() -> None:
    data = sim.toy2d(constraint="parabola", seed=0)
    train, test = data.split(0.3, 0)
    s, model = timed(lambda: LinearConstraint().fit(train.X, train.U))
    emit("learn-a/linear", "toy2d parabola, polynomial degree 1", train.n_samples, 2, s, "test NPPE",
         nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U).value)


def bench_ncl(n: int = 10_000, k: int = 100) -> None:
    rng = np.random.default_rng(0)
    a = unit_rows(rng.normal(size=(1, 2)))[0]
    X = rng.uniform(-1, 1, (n, 2))
    w = (-0.5 * X) - np.outer((-0.5 * X) @ a, a)
    v = np.outer(rng.uniform(-1, 1, n), a)
    U = v + w + rng.normal(scale=0.01, size=X.shape)
    s, model = timed(lambda: NullSpaceComponent(n_centres=k).fit(X, U), repeats=1)
    emit("learn-v/ncl", f"toy2d fixed constraint, {k} RBFs", n, 2, s, "train NUPE(w)",
         nupe(w, model.predict(X)).value)


def bench_policy() -> None:
    data = sim.varying_constraint(noise=0.01, seed=0)
    train, test = data.split(0.2, 0)
    grid = {"kind": "rbf", "n_centres": 100, "centres": "grid", "sigma2": 0.5}
    for method in ("pi", "pi-weighted", "pi-coupled", "lwpi", "dpl"):
        s, model = timed(lambda m=method: PolicyLearner(method=m, basis=grid).fit(
            train.X, train.U, train.true_projection()))
        emit(f"learn-pi/{method}", "varying_constraint noise 0.01", train.n_samples, 2, s, "test NUPE",
             nupe(test.truth["pi"], model.predict(test.X)).value)


def main() -> int:
    bench_nhat()
    bench_alpha()
    bench_lambda()
    bench_linear()
    bench_ncl()
    bench_policy()
    return 0


if __name__ == "__main__":
    sys.exit(main())
