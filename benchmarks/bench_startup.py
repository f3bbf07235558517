"""End-to-end time of a small ``ccl run`` against ``python -c "import numpy"`` measured in the
same run (issue 19's bar: ≤ 10×, wall and CPU). One JSON object per line:

* per repeat: {"repeat", "ccl_wall_s", "ccl_cpu_s", "numpy_wall_s", "numpy_cpu_s",
  "ratio_wall", "ratio_cpu"} and, with ``--without-plots``, the same run with
  ``output.plots: false`` ("noplots_wall_s", "noplots_cpu_s", "noplots_ratio_wall",
  "noplots_ratio_cpu") and, with ``--with-help``, ``ccl --help`` ("help_*"). The commands
  run back to back in an order that rotates every repeat, so the machine's drift hits them
  alike; CPU is the child's user + system time (``resource.getrusage(RUSAGE_CHILDREN)``
  before/after each child), its drawing process included;
* then {"config", "repeats", "bar", "median_ratio_wall", "median_ratio_cpu", "met_wall",
  "met_cpu", "run_bar_cpu" and "run_met_cpu" (issue 31's bar: ≤ 8× in CPU), the median seconds of
  each command, "bytecode", "load_before", "load_after",
  "cpus"} (and "noplots_median_ratio_wall" / "_cpu", "help_median_ratio_wall" / "_cpu",
  "help_bar", "help_met_cpu");
* with ``--phases``: the seconds (wall and CPU) of the run's phases, measured in one more
  process: imports, reading, stages, matplotlib's import, each figure.

The package's modules are compiled to bytecode first (``compileall``), as installing it does:
an environment with ``PYTHONDONTWRITEBYTECODE=1`` and no cache would otherwise compile every
module from source in every run (``--source`` removes the caches and measures that;
"bytecode" says which was measured).

Run:  python benchmarks/bench_startup.py [--repeats 9] [--without-plots] [--with-help] [--phases]
      [--config configs/toy2d_learn_pi.yaml]
"""

from __future__ import annotations

import argparse
import compileall
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

import yaml

ROOT = Path(__file__).resolve().parent.parent
BAR = 10.0
#: issue 31: `ccl --help` against `import numpy`
HELP_BAR = 1.3
#: issue 31: the small run against `import numpy`, in CPU
RUN_BAR = 8.0


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


def without_plots(config: Path, folder: Path) -> Path:
    """A copy of ``config`` with ``output.plots: false`` and its data paths made absolute."""
    raw = yaml.safe_load(config.read_text())
    files = raw["data"]["files"]
    raw["data"]["files"] = [str((config.parent / f).resolve()) for f in
                            ([files] if isinstance(files, str) else files)]
    raw["output"] = {**(raw.get("output") or {}), "plots": False}
    path = folder / f"{config.stem}-noplots.yaml"
    path.write_text(yaml.safe_dump(raw, sort_keys=False))
    return path


PHASES = r"""
import json, sys, time
def now():
    return time.perf_counter(), time.process_time()
t0 = now()
from pathlib import Path
import ccl_cli.cli  # the CLI module as `ccl` imports it
t_cli = now()
from ccl_cli import config as C
from ccl_cli.app.run import read_data
from ccl_cli.app.stages import Pipeline
t_imp = now()
cfg = C.load(sys.argv[1])
data, masks = read_data(cfg, None)
t_read = now()
from ccl_cli.learn import blas
with blas.threads(blas.RUN_THREADS):  # as run_to_dir does
    p = Pipeline(cfg.spec, data, masks)
    p.run(cfg.stages())
t_stages = now()
from ccl_cli.render.drawing import draw_views
out = Path(sys.argv[2]); out.mkdir(parents=True, exist_ok=True)
seconds = {}
t_p0 = now()
with blas.threads(blas.RUN_THREADS):
    draw_views(out, p.views(), seconds)  # one process
t_plots = now()
def span(a, b):
    return {"wall_s": round(b[0] - a[0], 3), "cpu_s": round(b[1] - a[1], 3)}
print(json.dumps({"import_cli": span(t0, t_cli), "import_pipeline": span(t_cli, t_imp),
                  "read": span(t_imp, t_read), "stages": span(t_read, t_stages),
                  "plots": span(t_p0, t_plots),
                  "matplotlib_import_wall_s": round(seconds.pop("matplotlib import", 0.0), 3),
                  "figure_wall_s": {k: round(s, 3) for k, s in seconds.items()}}))
"""


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--repeats", type=int, default=9)
    ap.add_argument("--config", default="configs/toy2d_learn_pi.yaml")
    ap.add_argument("--without-plots", action="store_true",
                    help="also time the run with output.plots: false")
    ap.add_argument("--phases", action="store_true", help="also time the run's phases in one process")
    ap.add_argument("--with-help", action="store_true",
                    help="also time `ccl --help` (issue 31's bar: ≤ 1.3× `import numpy`)")
    ap.add_argument("--source", action="store_true",
                    help="remove the package's bytecode caches first instead (with "
                         "PYTHONDONTWRITEBYTECODE=1: every run compiles from source)")
    args = ap.parse_args()
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    if args.source:  # no cached bytecode: with PYTHONDONTWRITEBYTECODE=1 every run compiles
        for cache in (ROOT / "ccl_cli").rglob("__pycache__"):
            shutil.rmtree(cache, ignore_errors=True)
        bytecode = "source" if env.get("PYTHONDONTWRITEBYTECODE") else "compiled by the warm-up run"
    else:
        compileall.compile_dir(ROOT / "ccl_cli", quiet=1)
        bytecode = "compiled"
    ccl = shutil.which("ccl") or ""
    tmp = Path(tempfile.mkdtemp(prefix="ccl-bench-startup-"))
    try:
        def run(config: str | Path, name: str) -> list[str]:
            return ([ccl] if ccl else [sys.executable, "-m", "ccl_cli.cli"]) + \
                ["run", str(config), "--out", str(tmp / name), "--force", "-q"]

        commands = {"ccl": run(args.config, "out"), "numpy": [sys.executable, "-c", "import numpy"]}
        if args.without_plots:
            commands["noplots"] = run(without_plots(ROOT / args.config, tmp), "noplots")
        if args.with_help:
            commands["help"] = ([ccl] if ccl else [sys.executable, "-m", "ccl_cli.cli"]) + ["--help"]
        for cmd in commands.values():
            timed(cmd, env)  # warm the file cache and matplotlib's font cache
        load = os.getloadavg()[0]
        rows = []
        names = list(commands)
        for i in range(args.repeats):
            got = {}
            for name in names[i % len(names):] + names[:i % len(names)]:
                got[name] = timed(commands[name], env)
            row: dict[str, float | int] = {"repeat": i}
            for name, (wall, cpu) in got.items():
                row[f"{name}_wall_s"], row[f"{name}_cpu_s"] = round(wall, 3), round(cpu, 3)
            for name in names:
                if name != "numpy":
                    prefix = "" if name == "ccl" else f"{name}_"
                    row[f"{prefix}ratio_wall"] = round(got[name][0] / got["numpy"][0], 2)
                    row[f"{prefix}ratio_cpu"] = round(got[name][1] / max(got["numpy"][1], 1e-3), 2)
            rows.append(row)
            print(json.dumps(row), flush=True)

        def med(key: str) -> float:
            return round(statistics.median(r[key] for r in rows), 3)

        summary: dict[str, object] = {"config": args.config, "repeats": args.repeats, "bar": BAR,
                                      "median_ratio_wall": med("ratio_wall"),
                                      "median_ratio_cpu": med("ratio_cpu"),
                                      "met_wall": med("ratio_wall") <= BAR,
                                      "met_cpu": med("ratio_cpu") <= BAR,
                                      "run_bar_cpu": RUN_BAR, "run_met_cpu": med("ratio_cpu") <= RUN_BAR}
        for name in ("noplots", "help"):
            if name in commands:
                summary |= {f"{name}_median_ratio_wall": med(f"{name}_ratio_wall"),
                            f"{name}_median_ratio_cpu": med(f"{name}_ratio_cpu")}
        if args.with_help:
            summary |= {"help_bar": HELP_BAR, "help_met_cpu": med("help_ratio_cpu") <= HELP_BAR}
        for name in names:
            summary |= {f"median_{name}_wall_s": med(f"{name}_wall_s"),
                        f"median_{name}_cpu_s": med(f"{name}_cpu_s")}
        summary |= {"bytecode": bytecode, "load_before": round(load, 2),
                    "load_after": round(os.getloadavg()[0], 2), "cpus": os.cpu_count()}
        print(json.dumps(summary), flush=True)
        if args.phases:
            out = subprocess.run([sys.executable, "-c", PHASES, args.config, str(tmp / "phases")], env=env,
                                 cwd=ROOT, capture_output=True, text=True, check=True)
            print(out.stdout.strip(), flush=True)
    finally:
        shutil.rmtree(tmp, ignore_errors=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
