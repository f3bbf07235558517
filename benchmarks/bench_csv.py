"""CSV reader memory: peak against the arrays read, for a normal-width table and a wide one.
Prints one JSON object.

* ``normal``: N rows (default 10⁶) of a rosbag→CSV-like export — integer ns time stamps and
  14 numeric columns (7 positions, 7 velocities), of which the config reads the 7 positions
  (state) and the 7 velocities (action). The loader runs in a fresh process under
  tracemalloc (NumPy's buffers included): ``peak_mb`` over ``arrays_mb`` (X, U and t of the
  demonstrations returned) is ``peak_ratio``.
* ``wide``: a CSV of about 128 MB with 10⁶ columns of which the config reads 3 (time, and a
  state of 2 columns, the action derived): ``ccl learn-a`` and ``ccl inspect`` in fresh
  processes, each with its peak RSS (``ru_maxrss`` of the child) and seconds; the same
  for ``ccl inspect`` of a 10-row CSV as the floor (``floor_rss_mb``: the interpreter and
  the libraries a command imports).

With ``--before DIR`` (a source tree of ccl_cli, e.g. ``git archive main | tar -x -C DIR``)
the same runs use that tree too (``before_*`` keys), interleaved.

Run:  python benchmarks/bench_csv.py [--rows 1000000] [--wide-mb 128] [--before DIR]
"""

from __future__ import annotations

import argparse
import json
import os
import subprocess
import sys
import tempfile
from pathlib import Path

import numpy as np

LOADER = r"""
import json, sys, tracemalloc
tracemalloc.start()
from ccl_cli.io import load_demonstrations
data = load_demonstrations(json.loads(sys.argv[1]))
peak = tracemalloc.get_traced_memory()[1]
arrays = data.X.nbytes + data.U.nbytes + data.t.nbytes
print(json.dumps({"peak_mb": peak / 2**20, "arrays_mb": arrays / 2**20, "samples": int(data.n_samples)}))
"""


def normal_csv(path: Path, rows: int) -> dict:
    """A rosbag→CSV-like table: ns stamps, 7 positions, 7 velocities."""
    rng = np.random.default_rng(0)
    t = 1_700_000_000_000_000_000 + np.arange(rows, dtype=np.int64) * 10_000_000
    names = ["%time", *(f"q{j}" for j in range(7)), *(f"dq{j}" for j in range(7))]
    with open(path, "w") as f:
        f.write(",".join(names) + "\n")
        for lo in range(0, rows, 100_000):
            hi = min(rows, lo + 100_000)
            block = np.round(rng.normal(size=(hi - lo, 14)), 6)
            lines = [f"{t[lo + i]}," + ",".join(map(repr, row)) for i, row in enumerate(block.tolist())]
            f.write("\n".join(lines) + "\n")
    return {"files": [str(path)], "state": {"columns": [f"q{j}" for j in range(7)]},
            "action": {"columns": [f"dq{j}" for j in range(7)]}, "time": {"column": "%time", "unit": "ns"}}


def wide_csv(path: Path, megabytes: float, columns: int = 1_000_000) -> Path:
    """About ``megabytes`` of rows of ``columns`` one-decimal numbers; the first is time (s)."""
    rng = np.random.default_rng(1)
    rows = max(2, int(megabytes * 1e6 / (4 * columns)))
    with open(path, "w") as f:
        f.write(",".join(["time", *(f"c{j}" for j in range(1, columns))]) + "\n")
        for i in range(rows):
            values = np.round(rng.random(columns - 1), 1).astype(str)
            f.write(f"{i * 0.01:.2f}," + ",".join(values.tolist()) + "\n")
    config = path.with_suffix(".yaml")
    config.write_text("data:\n  state: {columns: [c1, c2]}\n  action: {derive: state, window: 5}\n"
                      "  time: {column: time}\nlearn-a: {method: nhat}\nstages: [learn-a]\n"
                      "output: {plots: false}\n")
    return config


def _env(src: Path | None) -> dict:
    env = dict(os.environ)
    if src is not None:
        env["PYTHONPATH"] = str(src)
    return env


def loader(cfg: dict, src: Path | None, cwd: str) -> dict:
    """The loader in a fresh process (in ``cwd``: not a checkout, whose ccl_cli would shadow
    ``src``) under tracemalloc."""
    out = subprocess.run([sys.executable, "-c", LOADER, json.dumps(cfg)], capture_output=True, text=True,
                         env=_env(src), check=True, cwd=cwd)
    res = json.loads(out.stdout)
    res["peak_ratio"] = res["peak_mb"] / res["arrays_mb"]
    return {k: round(v, 3) if isinstance(v, float) else v for k, v in res.items()}


def command(argv: list[str], src: Path | None, cwd: str) -> dict:
    """A ccl command in a fresh process (started by a child of its own, so that ru_maxrss
    is this command's alone): exit status, seconds, peak RSS (MB), last stderr line."""
    code = ("import json, resource, subprocess, sys, time; t0 = time.monotonic(); "
            "p = subprocess.run(sys.argv[1:], stdout=subprocess.DEVNULL, stderr=subprocess.PIPE, text=True); "
            "u = resource.getrusage(resource.RUSAGE_CHILDREN); "
            "print(json.dumps({'exit': p.returncode, 'seconds': round(time.monotonic() - t0, 2), "
            "'peak_rss_mb': round(u.ru_maxrss / 1024, 1), 'error': p.stderr.strip().splitlines()[-1:]}))")
    out = subprocess.run([sys.executable, "-c", code, sys.executable, "-m", "ccl_cli.cli", *argv], cwd=cwd,
                         env=_env(src), capture_output=True, text=True, check=True)
    return json.loads(out.stdout)


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--rows", type=int, default=1_000_000)
    ap.add_argument("--wide-mb", type=float, default=128.0)
    ap.add_argument("--before", type=Path, default=None, help="a source tree of ccl_cli to compare")
    args = ap.parse_args()
    trees = [("", None)] + ([("before_", args.before.resolve())] if args.before else [])
    result: dict = {"benchmark": "csv", "rows": args.rows}
    with tempfile.TemporaryDirectory(prefix="ccl-csv-") as tmp:
        root = Path(tmp)
        cfg = normal_csv(root / "normal.csv", args.rows)
        result["normal_file_mb"] = round((root / "normal.csv").stat().st_size / 2**20, 1)
        for prefix, src in trees:
            result[f"{prefix}normal"] = loader(cfg, src, tmp)
        (root / "normal.csv").unlink()
        config = wide_csv(root / "wide.csv", args.wide_mb)
        small = root / "small.csv"
        small.write_text("time,a\n" + "".join(f"{i * 0.1:.1f},{i}\n" for i in range(10)))
        result["wide_file_mb"] = round((root / "wide.csv").stat().st_size / 2**20, 1)
        for prefix, src in trees:
            result[f"{prefix}floor_rss_mb"] = command(["inspect", str(small), "-q"], src, tmp)["peak_rss_mb"]
            result[f"{prefix}wide_learn_a"] = command(["learn-a", "wide.csv", "-c", str(config), "-o", "out",
                                                       "--force", "-q", "--test-fraction", "0"], src, tmp)
            result[f"{prefix}wide_inspect"] = command(["inspect", "wide.csv", "-q"], src, tmp)
    sys.stdout.write(json.dumps(result) + "\n")


if __name__ == "__main__":
    main()
