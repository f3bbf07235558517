"""The default pipeline at the size of real logs (issue 31): ``ccl run`` with ``stages: [learn-v,
learn-a, learn-pi]`` and a data mapping only (every learner at its defaults, figures on), at 10⁴,
10⁵, 10⁶ (and, asked for, 10⁷) samples, against a floor process in the same run.

The floor is a fresh Python process that reads the same canonical HDF5 file with h5py (every
demonstration's x and u), and computes their covariance and one least-squares solve
(u on [x, 1]) — what any program that learns from the file must at least do. On a shared machine
wall time varies with the load, so every figure is CPU seconds (user + system of the child and the
children it waited for, from ``wait4``) and a ratio to the floor measured next to it: each run is
paired, floor → pipeline → floor, and its ratio divides by the mean of its two floors.

Cases (``ccl simulate``; the size n is the number of samples asked for):

* ``tracker_plane``: 10 recordings at 50 Hz of n/500 s each (a plane: the states' geometry decides);
* ``arm7_free``: joint-space arm, n/1000 demonstrations of 1000 steps, a constraint along the
  Jacobian (the states' geometry finds nothing: the velocity candidates decide);
* ``toy2d_varying``: n/100 demonstrations of ≤ 100 steps, a constraint per demonstration, a task
  part (the issue's crash case: demonstrations of a few samples).

One JSON object per line:

* per run: {"case", "size", "samples", "repeat", "cpu_s", "floor_cpu_s", "ratio_cpu", "wall_s",
  "peak_rss_mib", "floor_peak_rss_mib", "ratio_rss", "stages": {stage: {"cpu_s", "ratio_cpu"}},
  "k", "status", "exit"};
* per case: {"case", "sizes", "median_ratio_cpu", "growth": [{"from", "to", "exponent"}] — the
  exponent of CPU seconds in the number of samples between consecutive sizes — "peak_rss_mib"};
* last: {"bars": the issue's bars for tracker_plane at 10⁵ and 10⁶ (CPU ≤ 40× the floor, every
  stage ≤ 20×, exponent ≤ 1.05, peak RSS ≤ 3× the floor's; learn-pi ≤ 20× at 10⁶), each with its
  figure and whether it holds; 10⁷: completes with peak RSS ≤ 6 GiB}.

Run:  python benchmarks/bench_pipeline.py [--sizes 1e4,1e5,1e6] [--cases tracker_plane,...]
      [--repeats 1] [--keep DIR]
"""

from __future__ import annotations

import argparse
import json
import math
import os
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
PIPELINE = "stages: [learn-v, learn-a, learn-pi]\n"
STAGES = ("learn-v", "learn-a", "learn-pi")


def simulate_args(case: str, n: int) -> list[str]:
    """``ccl simulate`` arguments of a case at about n samples."""
    if case == "tracker_plane":
        return ["tracker_plane", "--n-recordings", "10", "--duration", f"{n / 500:g}"]
    if case == "arm7_free":
        return ["arm7", "--constraint", "jacobian", "--n-demos", str(max(n // 1000, 2)), "--n-steps", "1000"]
    if case == "toy2d_varying":
        return ["toy2d", "--task", "--vary-constraint", "--n-steps", "100",
                "--n-demos", str(max(n // 100, 5))]
    raise SystemExit(f"unknown case {case!r}")


CASES = ("tracker_plane", "arm7_free", "toy2d_varying")

FLOOR = """
import sys
import h5py
import numpy as np
with h5py.File(sys.argv[1], "r") as f:
    demos = f["demos"]
    if "x" in demos:  # format 2: every demonstration's rows in one dataset
        X, U = demos["x"][()], demos["u"][()]
    else:  # format 1: a group per demonstration
        parts = [(demos[name]["x"][()], demos[name]["u"][()]) for name in demos]
        X, U = np.concatenate([p[0] for p in parts]), np.concatenate([p[1] for p in parts])
C = np.cov(np.c_[X, U], rowvar=False)
A = np.c_[X, np.ones(len(X))]
W = np.linalg.solve(A.T @ A, A.T @ U)
print(len(X), float(np.trace(C)), float(np.abs(W).sum()))
"""


def ccl(*args: str) -> list[str]:
    """The installed ``ccl`` script beside this Python."""
    return [str(Path(sys.executable).parent / "ccl"), *args]


def measured(cmd: list[str], env: dict[str, str] | None = None) -> dict:
    """Run ``cmd``: {"cpu_s" (user + system of it and its waited-for children), "wall_s",
    "peak_rss_mib" (the largest resident set of it or a child), "exit", "stdout", "stderr"}."""
    t = time.perf_counter()
    with tempfile.TemporaryFile() as out, tempfile.TemporaryFile() as err:
        proc = subprocess.Popen(cmd, cwd=ROOT, stdout=out, stderr=err, env=env)
        _, status, usage = os.wait4(proc.pid, 0)
        proc.returncode = os.waitstatus_to_exitcode(status)
        wall = time.perf_counter() - t
        out.seek(0)
        err.seek(0)
        return {"cpu_s": usage.ru_utime + usage.ru_stime, "wall_s": wall,
                "peak_rss_mib": usage.ru_maxrss / 1024, "exit": proc.returncode,
                "stdout": out.read().decode(errors="replace"), "stderr": err.read().decode(errors="replace")}


def floor(path: Path) -> dict:
    run = measured([sys.executable, "-c", FLOOR, str(path)])
    if run["exit"] != 0:
        raise SystemExit(f"the floor process failed on {path}: {run['stderr'][-500:]}")
    return run


def run_one(case: str, size: int, repeat: int, data: Path, tmp: Path) -> dict:
    """One paired run: floor, the pipeline, floor."""
    config = tmp / "pipeline.yaml"
    config.write_text(PIPELINE)
    out = tmp / f"{case}-{size}-{repeat}"
    before = floor(data)
    run = measured(ccl("run", str(config), "--data", str(data), "-o", str(out), "--force", "--json", "-q"))
    after = floor(data)
    f_cpu = (before["cpu_s"] + after["cpu_s"]) / 2
    f_rss = max(before["peak_rss_mib"], after["peak_rss_mib"])
    row = {"case": case, "size": size, "repeat": repeat, "exit": run["exit"],
           "cpu_s": round(run["cpu_s"], 2), "floor_cpu_s": round(f_cpu, 3),
           "ratio_cpu": round(run["cpu_s"] / f_cpu, 1), "wall_s": round(run["wall_s"], 1),
           "peak_rss_mib": round(run["peak_rss_mib"], 1), "floor_peak_rss_mib": round(f_rss, 1),
           "ratio_rss": round(run["peak_rss_mib"] / f_rss, 2)}
    if run["exit"] != 0:
        row["error"] = run["stderr"].strip()[-400:]
        return row
    summary = json.loads(run["stdout"])
    metrics = json.loads((out / "metrics.json").read_text())
    v = summary.get("validation", {})
    row["samples"] = int(v.get("n_train_samples", 0)) + int(v.get("n_test_samples", 0))
    row["stages"] = {s: {"cpu_s": round(metrics[s]["cpu_seconds"], 2),
                         "ratio_cpu": round(metrics[s]["cpu_seconds"] / f_cpu, 1)}
                     for s in STAGES if "cpu_seconds" in metrics.get(s, {})}
    if not row["stages"]:  # a ccl that does not record CPU per stage: its wall seconds
        row["stage_wall_s"] = {s: round(metrics[s]["seconds"], 2) for s in STAGES if s in metrics}
    row["k"] = metrics.get("learn-a", {}).get("n_constraints")
    row["chosen"] = metrics.get("learn-a", {}).get("selection", {}).get("chosen")
    row["status"] = summary.get("status")
    return row


def growth(rows: list[dict]) -> list[dict]:
    """The exponent of CPU seconds in the number of samples between consecutive sizes."""
    out = []
    by_size = sorted({r["size"] for r in rows})
    med = {s: statistics.median(r["cpu_s"] for r in rows if r["size"] == s) for s in by_size}
    n = {s: statistics.median(r.get("samples", s) for r in rows if r["size"] == s) for s in by_size}
    for a, b in zip(by_size, by_size[1:], strict=False):
        exponent = math.log(med[b] / med[a]) / math.log(n[b] / n[a])
        out.append({"from": a, "to": b, "exponent": round(exponent, 3)})
    return out


def bars(rows: list[dict], growths: dict[str, list[dict]]) -> list[dict]:
    """The issue's bars on the rows measured (those whose case and size ran)."""
    out = []

    def median(case: str, size: int, key) -> float | None:
        vals = [key(r) for r in rows if r["case"] == case and r["size"] == size and r["exit"] == 0]
        vals = [v for v in vals if v is not None]
        return statistics.median(vals) if vals else None

    for size in (10**5, 10**6):
        cpu = median("tracker_plane", size, lambda r: r["ratio_cpu"])
        if cpu is None:
            continue
        out.append({"bar": f"tracker_plane {size:.0e}: CPU ≤ 40× the floor", "value": cpu,
                    "holds": cpu <= 40})
        worst = median("tracker_plane", size, lambda r: max((s["ratio_cpu"] for s in r["stages"].values()),
                                                            default=None))
        if worst is not None:
            out.append({"bar": f"tracker_plane {size:.0e}: each stage ≤ 20× the floor", "value": worst,
                        "holds": worst <= 20})
        rss = median("tracker_plane", size, lambda r: r["ratio_rss"])
        out.append({"bar": f"tracker_plane {size:.0e}: peak RSS ≤ 3× the floor's", "value": rss,
                    "holds": rss <= 3})
    for g in growths.get("tracker_plane", []):
        if g["from"] >= 10**5 and g["to"] <= 10**6:
            out.append({"bar": "tracker_plane 1e5 → 1e6: growth exponent ≤ 1.05", "value": g["exponent"],
                        "holds": g["exponent"] <= 1.05})
    pi = median("tracker_plane", 10**6, lambda r: r["stages"].get("learn-pi", {}).get("ratio_cpu"))
    if pi is not None:
        out.append({"bar": "learn-pi at 1e6 ≤ 20× the floor", "value": pi, "holds": pi <= 20})
    for r in rows:
        if r["size"] >= 10**7:
            out.append({"bar": f"{r['case']} 1e7: completes, peak RSS ≤ 6 GiB", "value": r["peak_rss_mib"],
                        "holds": r["exit"] == 0 and r["peak_rss_mib"] <= 6 * 1024})
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--sizes", default="1e4,1e5,1e6",
                        help="comma-separated sample counts (1e7 takes minutes)")
    parser.add_argument("--cases", default=",".join(CASES))
    parser.add_argument("--repeats", type=int, default=1)
    parser.add_argument("--keep", type=Path, help="keep the recordings and outputs in this directory")
    args = parser.parse_args()
    sizes = [int(float(s)) for s in args.sizes.split(",")]
    cases = [c for c in args.cases.split(",") if c]
    rows: list[dict] = []
    growths: dict[str, list[dict]] = {}
    with tempfile.TemporaryDirectory(prefix="ccl-bench-pipeline-") as scratch:
        tmp = args.keep or Path(scratch)
        tmp.mkdir(parents=True, exist_ok=True)
        for case in cases:
            mine = []
            for size in sizes:
                data = tmp / f"{case}-{size}.h5"
                if not data.exists():
                    subprocess.run(ccl("simulate", *simulate_args(case, size), "-o", str(data), "--force",
                                       "-q"), cwd=ROOT, check=True)
                for r in range(args.repeats):
                    row = run_one(case, size, r, data, tmp)
                    print(json.dumps(row), flush=True)
                    mine.append(row)
            ok = [r for r in mine if r["exit"] == 0]
            growths[case] = growth(ok) if len({r["size"] for r in ok}) > 1 else []
            print(json.dumps({"case": case, "sizes": sizes,
                              "median_ratio_cpu": {s: statistics.median(r["ratio_cpu"] for r in ok
                                                                        if r["size"] == s)
                                                   for s in sizes if any(r["size"] == s for r in ok)},
                              "growth": growths[case],
                              "peak_rss_mib": {r["size"]: r["peak_rss_mib"] for r in ok}}), flush=True)
            rows += mine
    print(json.dumps({"bars": bars(rows, growths)}), flush=True)


if __name__ == "__main__":
    main()
