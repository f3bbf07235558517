"""End-to-end time of a small ``ccl run`` against ``python -c "import numpy"`` (issue 10's
bar: ≤ 15×). One JSON object per line:

* per repeat: {"repeat", "ccl_wall_s", "ccl_cpu_s", "numpy_wall_s", "numpy_cpu_s",
  "ratio_wall", "ratio_cpu"} — the two commands run back to back (order alternating), so
  the machine's drift hits both alike; CPU is the child's user + system time
  (``resource.getrusage(RUSAGE_CHILDREN)`` before/after each child);
* last: {"config", "repeats", "median_ratio_wall", "median_ratio_cpu", "median_ccl_wall_s",
  "median_ccl_cpu_s", "median_numpy_wall_s", "median_numpy_cpu_s", "load_before"} and, with
  ``--phases``, the wall seconds of the run's phases measured in one extra process
  (imports, read, stages, plots, writing).

Run:  python benchmarks/bench_startup.py [--repeats 9] [--config configs/toy2d_learn_pi.yaml]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import shutil
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def timed(cmd: list[str], env: dict[str, str]) -> tuple[float, float]:
    """(wall seconds, CPU seconds of the child) of one command, which must succeed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run(cmd, env=env, cwd=ROOT, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True, check=False)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode != 0:
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    cpu = (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)
    return wall, cpu


PHASES = r"""
import json, sys, time
t0 = time.perf_counter()
from pathlib import Path
import ccl_cli.cli  # the CLI module as `ccl` imports it
t_cli = time.perf_counter()
from ccl_cli import config as C
from ccl_cli.app.run import read_data
from ccl_cli.app.stages import Pipeline
t_imp = time.perf_counter()
cfg = C.load(sys.argv[1])
data, masks = read_data(cfg, None)
t_read = time.perf_counter()
from ccl_cli.learn import blas
with blas.threads(blas.stage_threads(data.n_samples)):  # as run_to_dir does
    p = Pipeline(cfg.spec, data, masks)
    p.run(cfg.stages())
t_stages = time.perf_counter()
from ccl_cli.render.figures import draw_views
out = Path(sys.argv[2]); out.mkdir(parents=True, exist_ok=True)
seconds = {}
t_p0 = time.perf_counter()
with blas.threads(blas.stage_threads(data.n_samples)):
    draw_views(out, p.views(), seconds)
t_plots = time.perf_counter()
times = [round(s, 3) for k, s in seconds.items() if k.endswith(".png")]
print(json.dumps({"import_cli_s": round(t_cli - t0, 3), "import_pipeline_s": round(t_imp - t_cli, 3),
                  "read_s": round(t_read - t_imp, 3), "stages_s": round(t_stages - t_read, 3),
                  "plots_s": round(t_plots - t_p0, 3), "save_per_figure_s": times}))
"""


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--config", default="configs/toy2d_learn_pi.yaml")
    ap.add_argument("--phases", action="store_true", help="also time the run's phases in one process")
    args = ap.parse_args()
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    ccl = shutil.which("ccl") or ""
    tmp = Path(tempfile.mkdtemp(prefix="ccl-bench-startup-"))
    try:
        run = ([ccl] if ccl else [sys.executable, "-m", "ccl_cli.cli"]) + \
              ["run", args.config, "--out", str(tmp / "out"), "--force", "-q"]
        numpy = [sys.executable, "-c", "import numpy"]
        timed(run, env)  # warm the file cache, the bytecode and matplotlib's font cache
        timed(numpy, env)
        load = os.getloadavg()[0]
        rows = []
        for i in range(args.repeats):
            pair = [(run, "ccl"), (numpy, "numpy")]
            if i % 2:
                pair.reverse()
            got = {}
            for cmd, name in pair:
                got[name] = timed(cmd, env)
            row = {"repeat": i, "ccl_wall_s": round(got["ccl"][0], 3), "ccl_cpu_s": round(got["ccl"][1], 3),
                   "numpy_wall_s": round(got["numpy"][0], 3), "numpy_cpu_s": round(got["numpy"][1], 3),
                   "ratio_wall": round(got["ccl"][0] / got["numpy"][0], 2),
                   "ratio_cpu": round(got["ccl"][1] / max(got["numpy"][1], 1e-3), 2)}
            rows.append(row)
            print(json.dumps(row), flush=True)

        def med(key: str) -> float:
            return round(statistics.median(r[key] for r in rows), 3)

        print(json.dumps({"config": args.config, "repeats": args.repeats,
                          "median_ratio_wall": med("ratio_wall"), "median_ratio_cpu": med("ratio_cpu"),
                          "median_ccl_wall_s": med("ccl_wall_s"), "median_ccl_cpu_s": med("ccl_cpu_s"),
                          "median_numpy_wall_s": med("numpy_wall_s"),
                          "median_numpy_cpu_s": med("numpy_cpu_s"),
                          "load_before": round(load, 2), "cpus": os.cpu_count()}), flush=True)
        if args.phases:
            out = subprocess.run([sys.executable, "-c", PHASES, args.config, str(tmp / "phases")], env=env,
                                 cwd=ROOT, capture_output=True, text=True, check=True)
            print(out.stdout.strip(), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
