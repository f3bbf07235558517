"""ccl batch throughput. One JSON object per line:
{"executor", "workers", "jobs", "seconds", "jobs_per_s"} and a final
{"speedup_2_over_1", "dask_overhead_per_job_s"}.

Run:  python benchmarks/bench_batch.py [--jobs 24]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

CONFIG = """
data:
  test: {fraction: 0.3, seed: 0}
learn-a: {method: linear, regressors: polynomial, degree: 1}
stages: [learn-a]
output: {plots: false}
"""


def timed_batch(jobs, out: Path, workers: int | None, scheduler: str | None) -> float:
    from ccl_cli.batch import run_batch

    t = time.perf_counter()
    results = run_batch(jobs, out, workers=workers, scheduler=scheduler, force=True)
    assert all(r.status == "ok" for r in results), [r.error for r in results if r.status != "ok"]
    return time.perf_counter() - t


def main() -> int:
    from ccl_cli import simulate as sim
    from ccl_cli.batch import plan
    from ccl_cli.io.hdf5 import write_demonstrations

    ap = argparse.ArgumentParser()
    ap.add_argument("--jobs", type=int, default=24)
    args = ap.parse_args()
    with tempfile.TemporaryDirectory() as tmp:
        root = Path(tmp)
        for i in range(args.jobs):
            write_demonstrations(root / f"r{i:03d}.h5", sim.toy2d(constraint="parabola", seed=i))
        (root / "p.yaml").write_text(CONFIG)
        jobs, _ = plan(files=[str(root / "r*.h5")], config=str(root / "p.yaml"))
        times = {}
        timed_batch(jobs[:2], root / "warm-local", 2, None)  # start the fork server once
        for workers in (1, 2):
            s = timed_batch(jobs, root / f"local{workers}", workers, None)
            times[workers] = s
            print(json.dumps({"executor": "local", "workers": workers, "jobs": len(jobs),
                              "seconds": round(s, 3), "jobs_per_s": round(len(jobs) / s, 2)}), flush=True)
        from distributed import LocalCluster

        with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                          dashboard_address=None) as cluster:
            timed_batch(jobs[:2], root / "warm", None, cluster.scheduler_address)  # worker imports
            s = timed_batch(jobs, root / "dask", None, cluster.scheduler_address)
        print(json.dumps({"executor": "dask", "workers": 2, "jobs": len(jobs), "seconds": round(s, 3),
                          "jobs_per_s": round(len(jobs) / s, 2)}), flush=True)
        print(json.dumps({"speedup_2_over_1": round(times[1] / times[2], 2),
                          "dask_overhead_per_job_s": round((s - times[2]) / len(jobs), 4)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
