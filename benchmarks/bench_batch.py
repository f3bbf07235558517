"""ccl batch: per-job overhead, 2-over-1 worker speed-up, Dask overhead. One JSON object per line:

* {"measure": "overhead", "demos_per_file", "jobs", "workers": 1, "seconds", "fit_s_per_job",
  "read_s_per_job", "overhead_per_job_s", "overhead_beyond_read_per_job_s", "load"}:
  N trivial jobs (one linear constraint on a toy recording, ~5 ms fit) at ``-j 1``;
  overhead = (batch wall − Σ stage seconds) / N, i.e. everything that is not the fit:
  worker hand-off, the job's content key (input hash), reading the recording, writing
  the job folder (model, metrics, report, run.json with versions and hashes). Reading
  is also shown on its own (it grows with the file: 9 HDF5 datasets per demonstration).
* {"measure": "cli", "seconds_1_job", "seconds", "seconds_per_job", "marginal_per_job_s"}:
  ``ccl batch -j 1`` in a fresh process on 1 and on N trivial 5-demonstration jobs (the
  fixed cost: imports, starting the workers, summary; the marginal cost of one more job).
* {"measure": "speedup", "jobs", "job_s_median" (at -j 1), "job_s_median_j2", "seconds_j1",
  "seconds_j2", "speedup_2_over_1", "blas_threads", "load"}: jobs of >= 0.5 s each (ncl,
  64 centres, 100 demonstrations) at ``-j 1`` then ``-j 2``, each in a fresh process as
  ``ccl batch`` runs them, timed after a warm-up batch; BLAS single-threaded by default
  (``--blas-threads``) so that the ratio measures the process parallelism (ccl's own
  default gives a ``-j 1`` worker the BLAS threads of every core). "pool_efficiency_j2" =
  Σ job seconds at -j 2 / (2 × wall): how busy the pool kept both workers; when a
  neighbour takes a core, each job slows down ("job_s_median_j2" > "job_s_median") and
  the speed-up falls below 2 although the efficiency stays near 1.
* {"measure": "dask", ...} (with ``--dask``): the trivial jobs on a 2-worker LocalCluster.
* {"measure": "open", "demos", "version", "ccl_s", "h5py_s", "numpy_floor_s"} (with
  ``--open``): opening a canonical file of 2,500 demonstrations with ccl
  (``read_demonstrations``), with bare h5py (every dataset of the layout read), and the
  floor of copying the same arrays in memory, for format versions 1 and 2.
* {"measure": "small_speedup", "jobs", "demos_per_file", "version", "seconds_j1", "seconds_j2",
  "speedup_2_over_1"} (with ``--small N``): ``ccl batch`` of N trivial jobs as a user runs it
  (a fresh process each) at ``-j 1`` and ``-j 2``, on files of format version 1 and 2,
  run back to back.

``load`` is the 1-minute load average before/after each measurement, and ``cpus`` the
cores: on a shared machine a busy neighbour takes cores from ``-j 2``. The package's modules
are compiled to bytecode first, as installing it does (with ``PYTHONDONTWRITEBYTECODE=1`` and
no cache, the command (and a fork server) would compile every module they import in every run).

Run:  python benchmarks/bench_batch.py [--jobs 24] [--long-jobs 8] [--dask] [--open] [--small 40]
"""

from __future__ import annotations

import argparse
import compileall
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

TRIVIAL = """
data:
  test: {fraction: 0.3, seed: 0}
learn-a: {method: linear, regressors: polynomial, degree: 1}
stages: [learn-a]
output: {plots: false}
"""
LONG = """
data:
  test: {fraction: 0.3, seed: 0}
learn-v: {n_centres: 64, tune: false}
stages: [learn-v]
output: {plots: false}
"""


def timed_batch(jobs, out: Path, workers: int | None, scheduler: str | None = None) -> tuple[float, list]:
    """``jobs`` run as ``ccl batch`` runs them: local workers forked from this process where it
    may fork (else from the fork server), or on the Dask cluster at ``scheduler``."""
    from ccl_cli.app.batch import can_fork, fork_workers, run_batch
    from ccl_cli.render.outputs import write_run

    t = time.perf_counter()
    pool = fork_workers(workers, (write_run.__module__,)) if scheduler is None and can_fork() else None
    results = run_batch(jobs, out, write_run, workers=workers, scheduler=scheduler, force=True, pool=pool)
    seconds = time.perf_counter() - t
    assert all(r.status == "ok" for r in results), [r.error for r in results if r.status != "ok"]
    return seconds, results


def timings(out: Path, results) -> list[dict[str, float]]:
    return [json.loads((out / "jobs" / r.job_id / "run.json").read_text())["timings"] for r in results]


def recordings(root: Path, n: int, demos: int, tag: str, version: int = 2) -> list[str]:
    from ccl_cli import simulate as sim
    from ccl_cli.io import write_demonstrations

    root.mkdir(parents=True, exist_ok=True)
    for i in range(n):
        data = sim.toy2d(constraint="parabola", n_demos=demos, seed=i)
        write_demonstrations(root / f"{tag}{i:03d}.h5", data, format_version=version)
    return [str(root / f"{tag}*.h5")]


def open_times(root: Path, demos: int = 2500) -> None:
    """Opening a canonical file of ``demos`` demonstrations: ccl, bare h5py, the in-memory floor."""
    import h5py
    import numpy as np

    from ccl_cli import simulate as sim
    from ccl_cli.io import read_demonstrations, write_demonstrations

    data = sim.toy2d(n_demos=demos, n_steps=20, seed=0)
    for version in (1, 2):
        path = write_demonstrations(root / f"open-v{version}.h5", data, format_version=version)
        t = time.perf_counter()
        read_demonstrations(path)
        ccl_s = time.perf_counter() - t
        t = time.perf_counter()
        with h5py.File(path, "r") as f:
            def read_all(name, obj):
                if isinstance(obj, h5py.Dataset):
                    obj[()]
            f["demos"].visititems(read_all)
        h5_s = time.perf_counter() - t
        t = time.perf_counter()
        for a in (data.X, data.U, data.t, *data.truth.values()):
            np.array(a, copy=True)
        floor = time.perf_counter() - t
        print(json.dumps({"measure": "open", "demos": demos, "version": version, "ccl_s": round(ccl_s, 3),
                          "h5py_s": round(h5_s, 3), "numpy_floor_s": round(floor, 4), "load": load()}),
              flush=True)


def small_speedup(root: Path, n: int, demos: int = 50) -> None:
    """``ccl batch`` of ``n`` trivial jobs at -j 1 and -j 2 (fresh processes), v1 and v2 files."""
    for version in (1, 2):
        files = recordings(root / f"small-v{version}", n, demos, "s", version)[0]
        seconds = {}
        for workers in (1, 2, 1, 2):  # each twice, alternating: the smaller of the two
            t = time.perf_counter()
            subprocess.run([*CCL, "batch", "--files", files, "-c", str(root / "trivial.yaml"), "-o",
                            str(root / f"out-small-v{version}-j{workers}"), "--force", "-q", "-j",
                            str(workers)], check=True, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            seconds[workers] = min(seconds.get(workers, float("inf")), time.perf_counter() - t)
        print(json.dumps({"measure": "small_speedup", "jobs": n, "demos_per_file": demos, "version": version,
                          "seconds_j1": round(seconds[1], 3), "seconds_j2": round(seconds[2], 3),
                          "speedup_2_over_1": round(seconds[1] / seconds[2], 2), "load": load(),
                          "cpus": os.cpu_count()}), flush=True)


CHILD = r"""
import json, statistics, sys, time
from pathlib import Path
sys.path.insert(0, sys.argv[3])
from bench_batch import timed_batch
from ccl_cli.app.batch import plan
root, workers = Path(sys.argv[1]), int(sys.argv[2])
warm, _ = plan(files=[str(root / "warm" / "w*.h5")], config=str(root / "trivial.yaml"))
timed_batch(warm, root / f"out-warm-j{workers}", workers)  # every module imported, files cached
jobs, _ = plan(files=[str(root / "long" / "l*.h5")], config=str(root / "long.yaml"))
seconds, results = timed_batch(jobs, root / f"out-long-j{workers}", workers)
print(json.dumps({"seconds": round(seconds, 3), "job_s_sum": round(sum(r.seconds for r in results), 3),
                  "job_s_median": round(statistics.median(r.seconds for r in results), 3)}))
"""


def fresh_process(root: Path, workers: int, blas_threads: int) -> dict[str, float]:
    """The long jobs at ``-j workers`` in a new process (as ``ccl batch`` runs them: the
    workers' BLAS threads follow the environment: ``blas_threads``, or with 0 ccl's default
    of cores / workers), timed after a warm-up batch."""
    env = dict(os.environ)
    for var in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS", "MKL_NUM_THREADS"):
        if blas_threads:
            env[var] = str(blas_threads)
        else:
            env.pop(var, None)
    out = subprocess.run([sys.executable, "-c", CHILD, str(root), str(workers), str(Path(__file__).parent)],
                         capture_output=True, text=True, check=True, env=env)
    return json.loads(out.stdout.strip().splitlines()[-1])


CCL = [shutil.which("ccl")] if shutil.which("ccl") else [sys.executable, "-m", "ccl_cli.cli"]


def load() -> float:
    return round(os.getloadavg()[0], 2)


def main() -> int:
    import logging

    from ccl_cli.app.batch import plan

    logging.getLogger("ccl").setLevel(logging.ERROR)
    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=24)
    ap.add_argument("--long-jobs", type=int, default=8)
    ap.add_argument("--blas-threads", type=int, default=1,
                    help="BLAS threads per worker in the speed-up runs (0: ccl's default, cores / workers); "
                         "1 measures process parallelism alone")
    ap.add_argument("--dask", action="store_true", help="also run the trivial jobs on a Dask LocalCluster")
    ap.add_argument("--open", action="store_true", help="opening a 2,500-demonstration file, v1 and v2")
    ap.add_argument("--small", type=int, default=0, help="ccl batch of this many small jobs, -j 1 and -j 2")
    ap.add_argument("--only-new", action="store_true", help="only --open and --small")
    args = ap.parse_args()
    compileall.compile_dir(Path(__file__).resolve().parents[1] / "ccl_cli", quiet=1)
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        (root / "trivial.yaml").write_text(TRIVIAL)
        (root / "long.yaml").write_text(LONG)
        if args.open:
            open_times(root)
        if args.small:
            small_speedup(root, args.small)
        if args.only_new:
            return 0
        warm, _ = plan(files=recordings(root / "warm", 2, 5, "w"), config=str(root / "trivial.yaml"))
        timed_batch(warm, root / "out-warm", 1)  # every module imported, files cached
        for demos in (5, 50):
            jobs, _ = plan(files=recordings(root / f"d{demos}", args.jobs, demos, "r"),
                           config=str(root / "trivial.yaml"))
            before = load()
            out = root / f"out-d{demos}"
            seconds, results = timed_batch(jobs, out, 1)
            t = timings(out, results)
            fit = sum(sum(v for k, v in x.items() if k not in ("total", "read")) for x in t)
            read = sum(x.get("read", 0.0) for x in t)
            n = len(jobs)
            print(json.dumps({"measure": "overhead", "demos_per_file": demos, "jobs": n, "workers": 1,
                              "seconds": round(seconds, 3), "fit_s_per_job": round(fit / n, 4),
                              "read_s_per_job": round(read / n, 4),
                              "overhead_per_job_s": round((seconds - fit) / n, 4),
                              "overhead_beyond_read_per_job_s": round((seconds - fit - read) / n, 4),
                              "load": [before, load()], "cpus": os.cpu_count()}), flush=True)
        # the command as a user runs it: a fresh process per batch (imports, workers' start, summary)
        cli = {}
        for n, files in ((1, str(root / "d5" / "r000.h5")), (args.jobs, str(root / "d5" / "r*.h5"))):
            t = time.perf_counter()
            subprocess.run([*CCL, "batch", "--files", files, "-c", str(root / "trivial.yaml"), "-o",
                            str(root / f"out-cli{n}"), "--force", "-q", "-j", "1"], check=True,
                           stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL)
            cli[n] = time.perf_counter() - t
        print(json.dumps({"measure": "cli", "jobs": args.jobs, "workers": 1,
                          "seconds_1_job": round(cli[1], 3), "seconds": round(cli[args.jobs], 3),
                          "seconds_per_job": round(cli[args.jobs] / args.jobs, 4),
                          "marginal_per_job_s": round((cli[args.jobs] - cli[1]) / (args.jobs - 1), 4),
                          "load": load()}), flush=True)
        if args.long_jobs:
            plan(files=recordings(root / "long", args.long_jobs, 100, "l"), config=str(root / "long.yaml"))
            before = load()
            runs = {w: fresh_process(root, w, args.blas_threads) for w in (1, 2)}
            print(json.dumps({"measure": "speedup", "jobs": args.long_jobs,
                              "job_s_median": runs[1]["job_s_median"],
                              "job_s_median_j2": runs[2]["job_s_median"],
                              "seconds_j1": runs[1]["seconds"], "seconds_j2": runs[2]["seconds"],
                              "speedup_2_over_1": round(runs[1]["seconds"] / runs[2]["seconds"], 2),
                              # Σ job seconds at -j 2 / (2 × wall): 1.0 when the pool keeps both
                              # workers busy, whatever a busy neighbour does to each job's time
                              "pool_efficiency_j2": round(runs[2]["job_s_sum"] / (2 * runs[2]["seconds"]), 2),
                              "blas_threads": args.blas_threads or "ccl's default (cores / workers)",
                              "load": [before, load()], "cpus": os.cpu_count()}), flush=True)
        if args.dask:
            from distributed import LocalCluster

            jobs, _ = plan(files=[str(root / "d5" / "r*.h5")], config=str(root / "trivial.yaml"))
            s_local, _ = timed_batch(jobs, root / "out-local2", 2)
            with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                              dashboard_address=None) as cluster:
                timed_batch(jobs[:2], root / "out-dask-warm", None, cluster.scheduler_address)
                s_dask, _ = timed_batch(jobs, root / "out-dask", None, cluster.scheduler_address)
            print(json.dumps({"measure": "dask", "workers": 2, "jobs": len(jobs),
                              "seconds": round(s_dask, 3), "local_seconds": round(s_local, 3),
                              "dask_overhead_per_job_s": round((s_dask - s_local) / len(jobs), 4)}),
                  flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
