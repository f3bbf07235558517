"""Scaling benchmark of the learning core (issue 10). One JSON object per line:

    {"learner", "problem", "N", "K", "seconds", "peak_mb", "mem_ratio", "test_error",
     "metric", "floor_seconds", "floor_ratio"}

* ``seconds`` — wall time of ``fit`` (one run, tracemalloc on);
* ``peak_mb`` / ``mem_ratio`` — peak traced memory of ``fit`` and its ratio to the input
  arrays (X, U and, for pi-coupled, the projections);
* ``test_error`` — on 10,000 held-out samples from the same simulator (another seed);
  with ``--error-seeds S`` also ``test_error_median`` / ``test_error_seeds`` over S training
  draws (seeds 0..S−1): one draw can be lucky (pi at 1e4: 0.12, 0.29, 0.37 on seeds 0–2);
* ``floor_seconds`` / ``floor_ratio`` — the one-pass floor: the time, in the same process
  and under the same conditions, of forming that learner's normal equations once
  (features of every sample and the Gram matrix of its regressor rows, in 8192-row chunks),
  and fit seconds divided by it.

alpha and lambda are fitted with their fixed default bases (``tune=False``: the 25 and 16
RBFs the rows name); a tuned fit cross-validates several candidates (3 folds each) before
the final fit, see ``benchmarks/bench_tuning.py``.

Run:  python benchmarks/bench_core.py [--quick] [--only NAME[,NAME]] [--sizes 1e4,1e5]
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
POLICY_BASIS = {"kind": "rbf", "n_centres": POLICY_K, "centres": "grid", "sigma2": 0.5}
LINEAR_IN_PARAMETERS = ("nhat", "linear", "pi", "pi-weighted", "pi-coupled", "lwpi", "dpl")


def emit(**row) -> None:
    print(json.dumps(row), flush=True)


def traced(fn: Callable[[], object]) -> tuple[float, float, object]:
    """(seconds, peak traced bytes, result) of one call."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    t = time.perf_counter()
    out = fn()
    seconds = time.perf_counter() - t
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return seconds, float(peak), out


def gram_floor(rows: Callable[[slice], np.ndarray], n: int) -> float:
    """Seconds to form Σ_n h_n h_nᵀ once, rows h built chunk by chunk by ``rows(slice)``."""
    t = time.perf_counter()
    G = None
    for start in range(0, n, CHUNK):
        H = rows(slice(start, min(start + CHUNK, n)))
        G = H.T @ H if G is None else G + H.T @ H
    return time.perf_counter() - t


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


# -- one benchmark row ----------------------------------------------------------------------
def setup(learner: str, n: int, k: int | None, options: dict | None, seed: int = 0) -> SimpleNamespace:
    """The problem of one row: training data of size n drawn with ``seed`` (test data: a
    fixed seed for the simulators, the next N_TEST samples for the toys), the fit, the
    inputs' bytes and the regressor rows of the one-pass floor."""
    test_seed = 1000
    if learner == "nhat":
        tr, te = toy(n, seed, constraint="fixed")
        fit = lambda: StateIndependentConstraint(selection="eigengap").fit(tr.X, tr.U)  # noqa: E731
        inputs = tr.X.nbytes + tr.U.nbytes
        floor_rows = lambda m, s: tr.U[s]  # noqa: E731
        problem, metric = "toy2d fixed uniform", "test NPPE"
    elif learner == "linear":
        tr, te = toy(n, seed, constraint="parabola")
        fit = lambda: LinearConstraint().fit(tr.X, tr.U)  # noqa: E731
        inputs = tr.X.nbytes + tr.U.nbytes
        floor_rows = lambda m, s: m._stack(tr.X[s], tr.U[s])  # noqa: E731
        problem, metric = "toy2d parabola uniform, polynomial 1", "test NPPE"
    elif learner == "alpha":
        tr, te = toy(n, seed, constraint="parabola")
        fit = lambda: StateDependentConstraint(tune=False).fit(tr.X, tr.U)  # noqa: E731
        inputs = tr.X.nbytes + tr.U.nbytes
        floor_rows = lambda m, s: kron_rows(m.basis_.transform(tr.X[s]), 1)  # noqa: E731
        problem, metric = "toy2d parabola uniform, 25 RBFs", "test NPPE"
    elif learner == "lambda":
        tr, te = arm(n, seed), arm(N_TEST, test_seed)
        fit = lambda: KnownFeatureConstraint(features="arm2", tune=False).fit(tr.X, tr.U)  # noqa: E731
        inputs = tr.X.nbytes + tr.U.nbytes

        def floor_rows(m, s):
            np.einsum("nrq,nq->nr", m.features_(tr.X[s]), tr.U[s])
            return kron_rows(m.basis_.transform(tr.X[s]), 1)

        problem, metric = "two_link, 16 RBFs", "test NPPE"
    elif learner == "ncl":
        tr, te = toy(n, seed, constraint="fixed", task=True)
        fit = lambda: NullSpaceComponent(n_centres=k, tune=False, **(options or {})).fit(tr.X, tr.U)  # noqa: E731
        inputs = tr.X.nbytes + tr.U.nbytes
        floor_rows = lambda m, s: kron_rows(m.basis_.transform(tr.X[s]), 2)  # noqa: E731
        problem, metric = f"toy2d fixed + task, {k} RBFs", "test NUPE(w)"
    else:  # policy learners
        tr, te = policy_problem(n, seed), policy_problem(N_TEST, test_seed)
        P = tr.true_projection() if learner == "pi-coupled" else None
        fit = lambda: PolicyLearner(method=learner, basis=POLICY_BASIS).fit(tr.X, tr.U, projections=P)  # noqa: E731
        inputs = tr.X.nbytes + tr.U.nbytes + (P.nbytes if P is not None else 0)
        if learner == "dpl":
            floor_rows = lambda m, s: m.basis_.transform(tr.X[s])  # noqa: E731
        elif learner == "lwpi":
            def floor_rows(m, s):
                B = m.basis_.transform(tr.X[s])
                phi = np.hstack([tr.X[s], np.ones((len(B), 1))])
                R = (phi[:, :, None] * tr.U[s][:, None, :]).reshape(len(B), -1)
                RR = (R[:, :, None] * R[:, None, :]).reshape(len(B), -1)
                return np.sqrt(np.abs(B.T @ RR))  # the (K, D²) accumulation, then a tiny Gram
        else:
            floor_rows = lambda m, s: kron_rows(m.basis_.transform(tr.X[s]), 2)  # noqa: E731
        problem, metric = "varying_constraint noise 0.01, 100-RBF grid", "test NUPE"
        k = POLICY_K
    return SimpleNamespace(tr=tr, te=te, fit=fit, inputs=inputs, floor_rows=floor_rows, problem=problem,
                           metric=metric, k=k)


def test_error(learner: str, model, te) -> float:
    if learner == "ncl":
        return nupe(te.truth["w"], model.predict(te.X)).value
    if learner in ("nhat", "linear", "alpha", "lambda"):
        return nppe(te.true_projection(), model.projection(te.X), te.truth["pi"], te.U).value
    return nupe(te.truth["pi"], model.predict(te.X)).value


def run(learner: str, n: int, k: int | None = None, options: dict | None = None,
        error_seeds: int = 1) -> None:
    c = setup(learner, n, k, options, 0)
    seconds, peak, model = traced(c.fit)
    err = test_error(learner, model, c.te)
    floor = min(gram_floor(lambda s: c.floor_rows(model, s), c.tr.n_samples) for _ in range(3))
    extra = {}
    if error_seeds > 1:  # the test error's spread over training draws (fits untimed)
        errs = [err] + [test_error(learner, (d := setup(learner, n, k, options, seed)).fit(), d.te)
                        for seed in range(1, error_seeds)]
        extra = {"test_error_median": float(f"{np.median(errs):.4g}"),
                 "test_error_seeds": [float(f"{e:.4g}") for e in errs]}
    emit(learner=learner, options=options or {}, problem=c.problem, N=c.tr.n_samples, K=c.k,
         seconds=round(seconds, 4),
         peak_mb=round(peak / 2**20, 2), mem_ratio=round(peak / c.inputs, 2),
         test_error=float(f"{err:.4g}"), metric=c.metric, floor_seconds=round(floor, 5),
         floor_ratio=round(seconds / floor, 1), **extra)


PLAN = [  # (learner, N values, K, options)
    ("nhat", (10_000, 100_000, 1_000_000), None, None),
    ("linear", (10_000, 100_000, 1_000_000), None, None),
    ("pi", (10_000, 100_000, 1_000_000), None, None),
    ("pi-weighted", (10_000, 100_000, 1_000_000), None, None),
    ("pi-coupled", (10_000, 100_000, 1_000_000), None, None),
    ("lwpi", (10_000, 100_000, 1_000_000), None, None),
    ("dpl", (10_000, 100_000, 1_000_000), None, None),
    ("ncl", (10_000, 100_000, 1_000_000), 16, None),
    ("ncl", (10_000, 100_000, 1_000_000), 16, {"polish": False}),
    ("ncl", (10_000,), 256, None),
    ("alpha", (10_000, 100_000), None, None),
    ("lambda", (10_000, 100_000), None, None),
]


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--quick", action="store_true", help="N = 1e4 only, ncl K = 16 only (smoke run)")
    ap.add_argument("--only", default="", help="comma-separated learners (e.g. ncl,alpha)")
    ap.add_argument("--sizes", default="", help="comma-separated N values to keep (e.g. 1e4,1e5)")
    ap.add_argument("--k", default="", help="ncl: comma-separated K values to keep")
    ap.add_argument("--error-seeds", type=int, default=1,
                    help="also fit on this many training draws and report the median test error")
    args = ap.parse_args(argv)
    only = set(filter(None, args.only.split(",")))
    sizes = {int(float(s)) for s in args.sizes.split(",") if s}
    ks = {int(s) for s in args.k.split(",") if s}
    for learner, ns, k, options in PLAN:
        if only and learner not in only:
            continue
        if ks and k is not None and k not in ks:
            continue
        if args.quick and k is not None and k > 16:
            continue
        for n in ns:
            if args.quick and n > 10_000:
                continue
            if sizes and n not in sizes:
                continue
            run(learner, n, k, options, args.error_seeds)
    return 0


if __name__ == "__main__":
    sys.exit(main())
