"""The same data and settings give a bit-identical model whatever the machine's load and its
BLAS threads (issue 17.6, issue 19.1): the search is counted in fits, nothing reads a clock,
and every learner fits with one BLAS thread (OpenBLAS's eigh, solve and some products give
other last bits with two). Seeds are fixed."""

import contextlib
import subprocess
import sys
import time
from pathlib import Path

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.learn import blas
from ccl_cli.learn.constraint import KnownFeatureConstraint, LinearConstraint, StateDependentConstraint
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.policy import PolicyLearner

ROOT = Path(__file__).resolve().parent.parent
TOY = sim.toy2d(constraint="parabola", seed=1, n_demos=20)
ARM = sim.two_link(seed=1, n_demos=16, n_steps=20)
NCL = sim.toy2d(task=True, sampling="uniform", n_samples=600, n_demos=12, seed=1)
POLICY = sim.toy2d(policy="limit_cycle", vary_constraint=True, sampling="uniform", n_samples=600, seed=1)
BIG = sim.toy2d(policy="limit_cycle", vary_constraint=True, sampling="uniform", n_samples=3000, seed=1)
#: 100 centres: a 200 × 200 eigen-decomposition, whose last bits OpenBLAS changes with its threads
WIDE_GRID = {"basis": [{"kind": "rbf", "n_centres": k, "centres": "kmeans"} for k in (49, 100)]}

LEARNERS = [
    ("ncl", lambda: NullSpaceComponent(), NCL),
    ("alpha", lambda: StateDependentConstraint(), TOY),
    ("lambda", lambda: KnownFeatureConstraint(features="arm2"), ARM),
    ("linear-rbf", lambda: LinearConstraint(regressors="rbf"), TOY),
    ("pi", lambda: PolicyLearner(method="pi"), POLICY),
    ("lwpi", lambda: PolicyLearner(method="lwpi"), POLICY),
    ("pi-100", lambda: PolicyLearner(method="pi", tune={"grid": WIDE_GRID}), BIG),
]


def learnt_arrays(model) -> list[np.ndarray]:
    """Every learnt array of a fitted model (weights, basis centres and widths)."""
    out = [np.asarray(v) for k, v in sorted(vars(model).items())
           if k.endswith("_") and not k.startswith("_") and isinstance(v, np.ndarray)]
    out += [np.asarray(w) for w in getattr(model, "weights_", [])]
    basis = getattr(model, "basis_", None)
    if basis is not None and hasattr(basis, "centres_"):
        out += [basis.centres_, np.array([basis.sigma2_])]
    return out


@pytest.mark.skipif(not blas.controllable(), reason="no BLAS whose threads can be set")
@pytest.mark.parametrize("name,make,data", LEARNERS, ids=[c[0] for c in LEARNERS])
def test_the_blas_thread_count_does_not_change_the_model(name, make, data):
    """Fitted with the process's BLAS at 1 and at 3 threads: the same bits (and a search ran)."""
    fits = []
    for threads in (1, 3):
        with blas.threads(threads):
            fits.append(make().fit(data.X, data.U, groups=data.demo))
    assert fits[0].tuning_ and fits[0].tuning_["chosen"] == fits[1].tuning_["chosen"]
    a, b = (learnt_arrays(m) for m in fits)
    assert len(a) == len(b) and len(a) >= 2
    for x, y in zip(a, b, strict=True):
        np.testing.assert_array_equal(x, y)


@pytest.mark.skipif(not blas.controllable(), reason="no BLAS whose threads can be set")
def test_without_the_one_thread_rule_the_thread_count_would_change_the_bits(monkeypatch):
    """What the test above guards against: with the learners' one-thread rule switched off,
    the 100-centre fit at 1 and 3 BLAS threads differs in its last bits (where the BLAS is
    threaded at all)."""
    real = blas.threads

    @contextlib.contextmanager
    def unpinned(n):
        if n == 1:  # the learners' own request: ignored
            yield None
        else:
            with real(n) as k:
                yield k

    monkeypatch.setattr(blas, "threads", unpinned)
    fits = []
    for threads in (1, 3):
        with real(threads):
            fits.append(PolicyLearner(method="pi", n_centres=100, tune=False).fit(BIG.X, BIG.U))
    if np.array_equal(fits[0].W_, fits[1].W_):
        pytest.skip("this BLAS gives the same bits at any thread count")
    np.testing.assert_allclose(fits[0].W_, fits[1].W_, rtol=1e-6, atol=1e-9)  # same fit, other last bits


def test_learn_v_gives_the_same_model_file_idle_and_under_full_cpu_load(tmp_path):
    """``ccl learn-v`` (the tuned default) on an idle machine, then with a busy-looping process
    per core: the two model.h5 files are byte-identical, and so is a third run with a clock
    that races ahead (nothing in the fit reads the time)."""
    data = tmp_path / "v.h5"
    assert main(["simulate", "toy2d", "-o", str(data), "--task", "--sampling", "uniform",
                 "--n-samples", "1500", "--seed", "3", "-q"]) == 0

    def learn_v(out: str) -> bytes:
        assert main(["learn-v", str(data), "-o", str(tmp_path / out), "-q"]) == 0
        return (tmp_path / out / "model.h5").read_bytes()

    idle = learn_v("idle")
    burners = [subprocess.Popen([sys.executable, "-c", "while True: pass"]) for _ in range(4)]
    try:
        time.sleep(0.2)
        loaded = learn_v("loaded")
    finally:
        for p in burners:
            p.kill()
            p.wait()
    assert loaded == idle
    clock = iter(range(0, 10**9, 1000))
    real = time.perf_counter, time.monotonic, time.process_time
    try:
        time.perf_counter = time.monotonic = time.process_time = lambda: float(next(clock))
        raced = learn_v("raced")
    finally:
        time.perf_counter, time.monotonic, time.process_time = real
    assert raced == idle
