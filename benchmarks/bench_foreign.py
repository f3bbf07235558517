"""Array- and table-format reader throughput. One JSON object per line:
{"format", "demos", "samples", "write_seconds", "read_seconds", "read_cpu_seconds", "samples_per_second",
"per_demo_ms"}. CPU time (this process) is the figure to compare on a shared machine.

A 7-D state/action recording of ``--demos`` demonstrations × ``--steps`` samples is written
by the third-party writers (h5py robomimic-like groups, scipy.io.savemat v5 cells, h5py in
MATLAB's v7.3 layout as matrices + demo index, the csv module: one table with a time column
in integer nanoseconds or in decimal seconds, demonstrations split on 1-s pauses) and read
back with ``load_demonstrations`` (best of ``--repeat``). The per-demonstration cost (group
walk, safety check of every link, one dataset read per variable) is what grows with the
number of groups; a table's cost is its body (parsing text, exact time stamps).

Run:  python benchmarks/bench_foreign.py [--demos 1000] [--steps 200] [--repeat 3]
"""

from __future__ import annotations

import argparse
import json
import sys
import tempfile
import time
from pathlib import Path

import numpy as np

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--demos", type=int, default=1000)
    ap.add_argument("--steps", type=int, default=200)
    ap.add_argument("--repeat", type=int, default=3)
    args = ap.parse_args()
    import scipy.io
    from test_foreign import ROBOMIMIC, write_mat73, write_robomimic

    from ccl_cli.io import load_demonstrations

    rng = np.random.default_rng(0)
    n, k = args.steps, args.demos
    X, U = rng.normal(size=(n * k, 7)), rng.normal(size=(n * k, 7))
    t = np.tile(np.arange(n) / 100.0, k)
    demo = np.repeat(np.arange(k), n)
    cells = [{"x": X[demo == d], "u": U[demo == d], "t": t[demo == d]} for d in range(k)]

    def obj(key):
        out = np.empty((1, k), dtype=object)
        for d in range(k):
            out[0, d] = cells[d][key].T
        return out

    def write_csv(path, decimal):
        import csv

        t_ns = 1_700_000_000_000_000_000 + np.round((t + demo * (n / 100.0 + 1.0)) * 1e9).astype(np.int64)
        stamps = [f"{s // 10**9}.{s % 10**9:09d}" for s in t_ns.tolist()] if decimal else t_ns.tolist()
        with open(path, "w", newline="") as f:
            w = csv.writer(f)
            w.writerow(["time", *(f"x{j}" for j in range(7)), *(f"u{j}" for j in range(7))])
            w.writerows([s, *row] for s, row in zip(stamps, np.hstack([X, U]).tolist(), strict=True))

    csv_cfg = {"state": {"columns": [f"x{j}" for j in range(7)]},
               "action": {"columns": [f"u{j}" for j in range(7)]}, "demos": {"split_on_gap": 0.5}}
    mat_cfg = {"format": "mat", "state": {"variable": "X", "samples": "columns"},
               "action": {"variable": "U", "samples": "columns"}, "time": {"rate": 100}}
    cases = {
        "hdf5-groups": (lambda p: write_robomimic(p, cells), ROBOMIMIC),
        "mat-v5-cells": (lambda p: scipy.io.savemat(p, {"X": obj("x"), "U": obj("u")}), mat_cfg),
        "mat-v7.3-index": (lambda p: write_mat73(p, {"X": X.T, "U": U.T, "demo": demo[None, :] + 1.0}),
                           {**mat_cfg, "demos": {"variable": "demo"}}),
        "csv-ns": (lambda p: write_csv(p, decimal=False), {**csv_cfg, "time": {"unit": "ns"}}),
        "csv-decimal-s": (lambda p: write_csv(p, decimal=True), csv_cfg),
    }
    with tempfile.TemporaryDirectory() as tmp:
        for name, (write, cfg) in cases.items():
            path = Path(tmp) / f"{name}.{name.split('-')[0].replace('hdf5', 'h5')}"
            t0 = time.perf_counter()
            write(path)
            wrote = time.perf_counter() - t0
            best = best_cpu = float("inf")
            for _ in range(args.repeat):
                t0, c0 = time.perf_counter(), time.process_time()
                data = load_demonstrations({**cfg, "files": [str(path)]})
                best = min(best, time.perf_counter() - t0)
                best_cpu = min(best_cpu, time.process_time() - c0)
            assert data.n_samples == n * k and data.n_demos == k
            print(json.dumps({"format": name, "demos": k, "samples": n * k, "write_seconds": round(wrote, 3),
                              "read_seconds": round(best, 4), "read_cpu_seconds": round(best_cpu, 4),
                              "samples_per_second": round(n * k / best),
                              "per_demo_ms": round(1e3 * best / k, 3)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
