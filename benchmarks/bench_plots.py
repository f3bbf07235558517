"""Seconds per report figure for every shipped config (issue 10's bar: < 0.5 s each).
One JSON object per line: {"config", "figure", "seconds"} per figure (its data, drawing
and PNG, as recorded in run.json's ``plot_seconds``), then per config {"config",
"figures", "max_s", "matplotlib_import_s", "run_s"}, and last {"max_s_over_all", "load"}.

Each config runs as ``ccl run`` in a fresh process, as a user runs it.

Run:  python benchmarks/bench_plots.py [--configs configs/toy2d_learn_pi.yaml ...]
"""

from __future__ import annotations

import argparse
import json
import os
import shutil
import subprocess
import sys
import tempfile
import time
from pathlib import Path

ROOT = Path(__file__).resolve().parent.parent


def main() -> int:
    ap = argparse.ArgumentParser()
    ap.add_argument("--configs", nargs="*", default=sorted(str(p.relative_to(ROOT))
                                                           for p in (ROOT / "configs").glob("*.yaml")))
    args = ap.parse_args()
    env = dict(os.environ)
    env["PYTHONPATH"] = str(ROOT) + (os.pathsep + env["PYTHONPATH"] if env.get("PYTHONPATH") else "")
    ccl = shutil.which("ccl")
    worst = 0.0
    with tempfile.TemporaryDirectory() as tmp:
        for config in args.configs:
            out = Path(tmp) / Path(config).stem
            cmd = ([ccl] if ccl else [sys.executable, "-m", "ccl_cli.cli"]) + \
                ["run", config, "--out", str(out), "--force", "-q"]
            t = time.perf_counter()
            proc = subprocess.run(cmd, cwd=ROOT, env=env, capture_output=True, text=True, check=False)
            run_s = time.perf_counter() - t
            if proc.returncode != 0:
                print(json.dumps({"config": config, "error": proc.stderr.strip()[-300:]}), flush=True)
                continue
            seconds = json.loads((out / "run.json").read_text()).get("plot_seconds", {})
            figures = {k: v for k, v in seconds.items() if k.endswith(".png")}
            for name, s in figures.items():
                print(json.dumps({"config": config, "figure": name, "seconds": round(s, 3)}), flush=True)
            top = max(figures.values(), default=0.0)
            worst = max(worst, top)
            print(json.dumps({"config": config, "figures": len(figures), "max_s": round(top, 3),
                              "matplotlib_import_s": round(seconds.get("matplotlib import", 0.0), 3),
                              "run_s": round(run_s, 3)}), flush=True)
    print(json.dumps({"max_s_over_all": round(worst, 3), "load": round(os.getloadavg()[0], 2)}), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
