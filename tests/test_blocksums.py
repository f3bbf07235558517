"""The block sums of a fit (ccl_cli/learn/blocksums.py) here and on a dask.distributed cluster: the
same function, the same normal equations (to rounding), the same learnt policy and run."""

import json

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.learn import blocksums
from ccl_cli.learn.policy import PolicyLearner

dask_cluster = pytest.importorskip("dask_cluster")  # tests/dask_cluster.py (needs distributed)


@pytest.fixture(scope="module")
def cluster():
    proc, info = dask_cluster.start(2)
    from distributed import Client

    client = Client(info["address"], timeout="30s")
    yield client, info["address"]
    client.close()
    dask_cluster.stop(proc)


def test_block_sums_here_are_the_left_fold_of_the_blocks():
    rng = np.random.default_rng(0)
    A = rng.standard_normal((1000, 4))

    def gram(a):
        return (a.T @ a, a.sum(0))

    M, s = blocksums.block_sums(gram, lambda i, j: (A[i:j],), len(A), 96)
    by_hand_M, by_hand_s = np.zeros((4, 4)), np.zeros(4)
    for i in range(0, 1000, 96):
        by_hand_M += A[i:i + 96].T @ A[i:i + 96]
        by_hand_s += A[i:i + 96].sum(0)
    assert np.array_equal(M, by_hand_M) and np.array_equal(s, by_hand_s)  # bit for bit
    assert np.allclose(M, A.T @ A, rtol=1e-12)
    assert blocksums.block_sums(gram, lambda i, j: (A[i:j],), 0, 96) is None


@pytest.mark.parametrize("method", ["pi-coupled", "dpl"])
def test_a_policy_learnt_on_a_cluster_is_the_one_learnt_here(cluster, method):
    from distributed import get_task_stream

    client, _ = cluster
    d = sim.toy2d(n_demos=100, seed=1)
    P = d.true_projection() if method == "pi-coupled" else None
    kw = {"method": method, "n_centres": 16, "tune": False, "chunk_size": 64, "seed": 0}
    here = PolicyLearner(**kw).fit(d.X, d.U, groups=d.demo, projections=P)
    blocks = -(-d.n_samples // 64)
    with get_task_stream(client) as tasks, blocksums.on_cluster(client):
        there = PolicyLearner(**kw).fit(d.X, d.U, groups=d.demo, projections=P)
    ran = [t for t in tasks.data if str(t["key"]).startswith("_task")]
    assert len(ran) == -(-blocks // blocksums.TASK_BLOCKS) > 1, tasks.data[:2]  # the blocks: on its workers
    # the sums grouped by task: rounding apart (dpl's weights 1e-11 of their largest, its normal
    # matrix ill-conditioned; the predictions 1e-13)
    assert np.abs(there.W_ - here.W_).max() <= 1e-9 * np.abs(here.W_).max()
    assert np.abs(there.predict(d.X) - here.predict(d.X)).max() <= 1e-10 * np.abs(here.predict(d.X)).max()


def test_ncl_learnt_on_a_cluster_is_the_one_learnt_here(cluster):
    """learn-v's Levenberg–Marquardt passes over all rows: the rows and their features held by
    the workers (sent once), each pass's JᵀJ, Jᵀr and Σ r² summed there block by block."""
    from distributed import get_task_stream

    from ccl_cli.learn.nullspace import NullSpaceComponent

    client, _ = cluster
    d = sim.toy2d(n_demos=100, task=True, seed=2)
    kw = {"n_centres": 16, "tune": False, "chunk_size": 64, "seed": 0}
    here = NullSpaceComponent(**kw).fit(d.X, d.U)
    with get_task_stream(client) as tasks, blocksums.on_cluster(client):
        there = NullSpaceComponent(**kw).fit(d.X, d.U)
    groups = len(blocksums.task_groups(d.n_samples, 64))
    passes = sum(s["full_passes"] + s["cost_passes"] for s in there.stages_ if s["rows"] == d.n_samples)
    sums = [t for t in tasks.data if str(t["key"]).startswith("_sum_task")]
    assert passes > 0 and len(sums) == passes * groups  # every pass over all rows: on the workers
    assert [s["stop"] for s in there.stages_] == [s["stop"] for s in here.stages_]
    # an iterative fit stopped at its tolerance: the paths part by rounding, the optima by less
    # than 1e-6 of w̃'s scale (5e-8 here), the costs by less than 1e-8 (the workers' last bits vary
    # from run to run: 8e-11 to 2.2e-9 over 13 runs)
    w_here, w_there = here.predict(d.X), there.predict(d.X)
    assert np.abs(w_there - w_here).max() <= 1e-6 * np.abs(w_here).max()
    assert there.cost_ == pytest.approx(here.cost_, rel=1e-8)
    with blocksums.on_cluster(client):  # the same rows sent again: their own keys on the cluster
        again = NullSpaceComponent(**kw).fit(d.X, d.U)  # (hashed keys: "lost dependencies")
    assert again.cost_ == pytest.approx(here.cost_, rel=1e-8)


def test_ccl_run_with_a_scheduler_learns_what_it_learns_alone(cluster, tmp_path, capsys):
    from distributed import get_task_stream

    from ccl_cli.io import write_demonstrations

    client, address = cluster
    data = write_demonstrations(tmp_path / "toy.h5", sim.toy2d(n_demos=100, task=True, seed=3))
    config = tmp_path / "run.yaml"
    config.write_text(f"data: {{files: [{data}]}}\nlearn-v: {{chunk_size: 64}}\n"
                      "learn-pi: {chunk_size: 64}\nstages: [learn-v, learn-a, learn-pi]\n")
    assert main(["run", str(config), "-o", str(tmp_path / "here"), "-q"]) == 0
    with get_task_stream(client) as tasks:
        assert main(["run", str(config), "-o", str(tmp_path / "there"), "-q", "--scheduler", address]) == 0
    keys = {str(t["key"]).split("-")[0] for t in tasks.data}
    assert {"_task", "_sum_task", "_map_task"} <= keys  # the policies' sums and ncl's passes: there
    here, there = (json.loads((tmp_path / p / "metrics.json").read_text()) for p in ("here", "there"))
    for stage in ("learn-v", "learn-a", "learn-pi"):  # normalised errors (1: as bad as zero), within 1e-6
        for part in {"train", "test"} & set(here[stage]):
            for name, m in here[stage][part].items():
                got = there[stage][part][name]["value"]
                assert got == pytest.approx(m["value"], rel=1e-6, abs=1e-6), (stage, name)


def test_an_unreachable_scheduler_is_one_line(tmp_path, capsys):
    from pathlib import Path

    config = Path(__file__).resolve().parent.parent / "configs" / "toy2d_learn_pi.yaml"
    code = main(["run", str(config), "-o", str(tmp_path / "x"), "-q", "--scheduler", "tcp://127.0.0.1:9"])
    err = capsys.readouterr().err.strip().splitlines()
    assert code == 2 and len(err) == 1 and "Dask scheduler" in err[0] and "Traceback" not in err[0]
    assert not (tmp_path / "x").exists()


def test_a_cluster_lost_before_a_fit_is_one_line():
    from distributed import Client

    from ccl_cli.errors import LearningError

    proc, info = dask_cluster.start(1)
    client = Client(info["address"], timeout="10s")
    dask_cluster.stop(proc)  # the scheduler and its worker are gone
    d = sim.toy2d(n_demos=100, seed=1)
    try:
        with blocksums.on_cluster(client), pytest.raises(LearningError) as lost:
            PolicyLearner(method="dpl", n_centres=16, tune=False, chunk_size=64).fit(d.X, d.U)
        message = str(lost.value)
        assert message.startswith("the Dask cluster could not compute the block sums of a fit (")
        assert "\n" not in message
    finally:
        client.close(timeout=2)
