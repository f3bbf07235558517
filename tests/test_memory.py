"""Memory flat in N (issue 19.3): the iterative learners keep no array of N × K features, no
N × d × d stack of frames and no N × r × q Jacobians; their peak traced memory stays within 5×
their input arrays. The test runs at a size that takes seconds, so it makes N large against
the fixed costs as they are at N = 1e6: the feature cache (kept only while small) is off, as it
is for large N, and the row blocks hold 1024 rows (a 60th of the data, as 8192 rows are of
5e5); bench_core.py --memory measures N = 1e6 itself."""

import tracemalloc

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.learn import basis as basis_module
from ccl_cli.learn import linalg
from ccl_cli.learn.constraint import KnownFeatureConstraint, StateDependentConstraint
from ccl_cli.learn.nullspace import NullSpaceComponent

N = 60_000


def peak_ratio(fit, *arrays) -> float:
    """Peak traced bytes of ``fit()`` over the bytes of the input arrays."""
    tracemalloc.start()
    tracemalloc.reset_peak()
    fit()
    peak = tracemalloc.get_traced_memory()[1]
    tracemalloc.stop()
    return peak / sum(a.nbytes for a in arrays)


@pytest.mark.parametrize("name", ["alpha", "lambda", "ncl"])
def test_peak_memory_of_a_fit_is_within_five_times_its_inputs(monkeypatch, name):
    monkeypatch.setattr(basis_module, "FEATURE_CACHE_FLOOR", 0)
    monkeypatch.setattr(linalg, "CHUNK_ROWS", 1024)
    if name == "lambda":
        data = sim.two_link(n_demos=N // 40, n_steps=40, seed=0)
        make = lambda: KnownFeatureConstraint(features="arm2", n_centres=36, tune=False)  # noqa: E731
    else:
        data = sim.toy2d(constraint="parabola" if name == "alpha" else "fixed", task=name == "ncl",
                         sampling="uniform", n_samples=N, n_demos=1, seed=0)
        make = (lambda: StateDependentConstraint(n_centres=36, tune=False)) if name == "alpha" else \
            (lambda: NullSpaceComponent(n_centres=36, tune=False))
    X, U = np.ascontiguousarray(data.X), np.ascontiguousarray(data.U)
    ratio = peak_ratio(lambda: make().fit(X, U), X, U)
    features = N * 36 * 8 / (X.nbytes + U.nbytes)  # what keeping β(X) alone would cost: 9×
    assert ratio <= 5.0 < features, (name, ratio)
