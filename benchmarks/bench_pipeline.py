"""The default pipeline at log scale (issue 17's bar: 60k samples within a minute on this
machine): ``ccl run`` with ``stages: [learn-v, learn-a, learn-pi]`` and a data mapping only
(every learner at its defaults, figures on), on simulated recordings of ~60,000 samples.

Each case writes its recording once with ``ccl simulate`` and then runs the pipeline
``--repeats`` times. One JSON object per line:

* per run: {"case", "samples", "wall_s", "cpu_s", "floor_wall_s", "floor_cpu_s",
  "ratio_cpu", "stages": {stage: seconds}, "k", "angle_deg", "status"} — the floor is
  ``ccl inspect`` of the same file (reading it, no learning), run just before;
* last: {"summary": case → median wall / CPU seconds, and whether the median wall time is
  under 60 s}.

Wall time on a shared VM varies with its load; the CPU seconds (user + system of the child)
are the stable figure. Run:  python benchmarks/bench_pipeline.py [--repeats 3] [--only arm7]
"""

from __future__ import annotations

import argparse
import json
import resource
import statistics
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent
#: name → ccl simulate arguments giving about 60,000 samples
CASES = {
    "tracker_plane_200Hz": ["tracker_plane", "--rate", "200", "--duration", "300"],
    "arm7_jacobian": ["arm7", "--constraint", "jacobian", "--n-demos", "60", "--n-steps", "1000"],
    "toy2d_parabola": ["toy2d", "--constraint", "parabola", "--n-demos", "570"],  # ~105 steps each
}
PIPELINE = "stages: [learn-v, learn-a, learn-pi]\n"


def ccl(*args: str) -> list[str]:
    """The installed ``ccl`` script beside this Python."""
    return [str(Path(sys.executable).parent / "ccl"), *args]


def timed(cmd: list[str]) -> tuple[float, float, str]:
    """(wall s, CPU s of the child, stdout) of one command, which must succeed."""
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    proc = subprocess.run(cmd, cwd=ROOT, capture_output=True, text=True, check=False)
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    if proc.returncode not in (0,):
        raise SystemExit(f"{' '.join(cmd)} failed ({proc.returncode}): {proc.stderr.strip()[-500:]}")
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime), proc.stdout


def run_case(name: str, sim: list[str], repeats: int, tmp: Path) -> list[dict]:
    data = tmp / f"{name}.h5"
    subprocess.run(ccl("simulate", *sim, "-o", str(data), "--force", "-q"), cwd=ROOT, check=True)
    config = tmp / f"{name}.yaml"
    config.write_text(PIPELINE)
    out = []
    for r in range(repeats):
        floor_wall, floor_cpu, _ = timed(ccl("inspect", str(data), "--json"))
        wall, cpu, stdout = timed(ccl("run", str(config), "--data", str(data), "-o", str(tmp / f"{name}-{r}"),
                                      "--force", "--json", "-q"))
        summary = json.loads(stdout)
        metrics = json.loads((tmp / f"{name}-{r}" / "metrics.json").read_text())
        a = metrics.get("learn-a", {})
        row = {"case": name, "repeat": r, "samples": summary.get("validation", {}).get("n_train_samples", 0)
               + summary.get("validation", {}).get("n_test_samples", 0),
               "wall_s": round(wall, 2), "cpu_s": round(cpu, 2), "floor_wall_s": round(floor_wall, 2),
               "floor_cpu_s": round(floor_cpu, 2), "ratio_cpu": round(cpu / max(floor_cpu, 1e-9), 1),
               "stages": {s: round(v.get("seconds", 0.0), 2) for s, v in metrics.items()
                          if isinstance(v, dict) and "seconds" in v},
               "k": a.get("n_constraints"), "angle_deg": (a.get("constraint") or {}).get("angle_deg"),
               "status": summary.get("status")}
        print(json.dumps(row), flush=True)
        out.append(row)
    return out


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--repeats", type=int, default=3)
    parser.add_argument("--only", nargs="*", choices=sorted(CASES))
    args = parser.parse_args()
    summary = {}
    with tempfile.TemporaryDirectory(prefix="ccl-bench-pipeline-") as tmp:
        for name in args.only or CASES:
            rows = run_case(name, CASES[name], args.repeats, Path(tmp))
            wall = statistics.median(r["wall_s"] for r in rows)
            summary[name] = {"samples": rows[0]["samples"], "median_wall_s": wall,
                             "median_cpu_s": statistics.median(r["cpu_s"] for r in rows),
                             "under_60_s": wall < 60.0}
    print(json.dumps({"summary": summary}))


if __name__ == "__main__":
    main()
