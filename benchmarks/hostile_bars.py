"""The bars of issue 20, measured: each targeted hostile input run through the ``ccl``
command line in its own process, with its exit status, wall time, peak RSS, stderr lines
and what it left behind. Prints one JSON object.

Cases: a 10-KB MATLAB v7.3 file declaring 10⁹ elements; a MATLAB v5 file holding a sparse
10⁶×10⁶ matrix; a compressed v7 file whose 7×40 variable inflates to 2 GB; a 2 GB CSV of
one line; FIFOs given as .csv/.bag/.mat/.h5, as a bag's metadata.yaml and as the storage
file (sqlite3, mcap) its metadata names; ``ccl batch -o`` on a user's folder, and under a
read-only parent (as an unprivileged user, via setpriv, when run as root); ``ulimit -f 8``
with learn-a and batch; damaged models (attribute tables damaged until libhdf5 fails
iterating them) through predict and inspect.

Cases of issue 28 (round 4): a Dask batch whose only worker, or whose scheduler, is SIGKILLed
mid-batch (a LocalCluster in processes of its own, tests/dask_cluster.py; seconds from the
kill to ccl's exit, its exit status and lines, and a local rerun's metrics against a clean
local run); ROS 1 bags declaring chunk and index positions outside the file; a 5,000-digit
integer in a config; a recording whose name is not UTF-8 (learn-a and a batch glob); a
3.4-MB YAML of 200,000 keys; a 128-MB CSV of 10⁶ columns of which 3 are read (learn-a and
inspect, peak RSS); ``--force`` onto a folder holding a look-alike run.json.

Every command runs as ``python -m ccl_cli.cli``, so ``PYTHONPATH=<a checkout>`` measures
another version of ccl (the "before" of a change).

Run:  python benchmarks/hostile_bars.py [--only NAME,...] [--big-csv-gb 2]
"""

from __future__ import annotations

import argparse
import json
import os
import random
import resource
import shutil
import signal
import subprocess
import sys
import tempfile
import time
from pathlib import Path
from typing import Any

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))
sys.path.insert(0, str(HERE))

CCL = [sys.executable, "-m", "ccl_cli.cli"]
STAGE = {"learn-a": {"method": "nhat"}, "stages": ["learn-a"], "output": {"plots": False}}


#: starts the command as its own child and writes that child's peak RSS (KB) to argv[1]: a
#: process started straight from this (large) one would count this one's pages in its ru_maxrss
#: (Linux keeps the high-water mark of the address space it replaces at exec)
LAUNCH = ("import os, resource, signal, subprocess, sys; p = subprocess.run(sys.argv[2:]); "
          "open(sys.argv[1], 'w').write(str(resource.getrusage(resource.RUSAGE_CHILDREN).ru_maxrss)); "
          "p.returncode < 0 and (signal.signal(-p.returncode, signal.SIG_DFL), os.kill(os.getpid(), "
          "-p.returncode)); sys.exit(p.returncode)")


def run(argv: list[str], cwd: Path, timeout: float = 60.0, preexec: Any = None,
        prefix: list[str] | None = None) -> dict[str, Any]:
    """Run one ccl command; exit status, wall and CPU seconds, peak RSS (MB, the command's own:
    :data:`LAUNCH`) and stderr lines."""
    err, rss = cwd / ".stderr", cwd / ".rss"
    t0 = time.monotonic()
    with open(err, "wb") as e:
        proc = subprocess.Popen([*(prefix or []), sys.executable, "-c", LAUNCH, rss, *CCL, *map(str, argv)],
                                cwd=cwd, stdin=subprocess.DEVNULL,
                                stdout=subprocess.DEVNULL, stderr=e, preexec_fn=preexec,
                                start_new_session=True)
        code: int | None = None
        while time.monotonic() - t0 < timeout:
            pid, status, usage = os.wait4(proc.pid, os.WNOHANG)
            if pid:
                code = os.waitstatus_to_exitcode(status)
                break
            time.sleep(0.005)
        else:
            os.killpg(proc.pid, signal.SIGKILL)
            _, _, usage = os.wait4(proc.pid, 0)
    seconds = time.monotonic() - t0
    lines = [ln for ln in err.read_text(errors="replace").splitlines() if ln.strip()]
    err.unlink()
    peak = int(rss.read_text()) if rss.exists() else usage.ru_maxrss  # killed: at least the launcher's
    rss.unlink(missing_ok=True)
    return {"exit": code, "seconds": round(seconds, 2), "cpu_s": round(usage.ru_utime + usage.ru_stime, 2),
            "peak_rss_mb": round(peak / 1024, 1),
            "stderr_lines": len(lines), "first_line": lines[0][:200] if lines else ""}


def _yaml(path: Path, value: Any) -> Path:
    import yaml

    path.write_text(yaml.safe_dump(value, sort_keys=False))
    return path


# -- the inputs ---------------------------------------------------------------------------------
def mat73_bomb(root: Path) -> tuple[Path, Path]:
    """A MATLAB v7.3 file of a few KB whose X declares 10⁹ doubles and holds none."""
    import h5py
    import writers

    path = writers.write_mat73(root / "bomb73.mat", {"U": [[1.0, 2.0]]})
    with h5py.File(path, "a") as f:
        ds = f.create_dataset("X", shape=(1_000_000_000, 1), dtype="f8", chunks=(1 << 16, 1))
        ds.attrs["MATLAB_class"] = b"double"
    cfg = _yaml(root / "mat73.yaml", {"data": {"state": {"variable": "X"}, "time": {"rate": 10}}, **STAGE})
    return path, cfg


def mat5_sparse(root: Path) -> tuple[Path, Path]:
    """A MATLAB v5 file whose X is a sparse 10⁶×10⁶ matrix (7.3 TiB dense)."""
    import numpy as np
    import scipy.io
    import scipy.sparse

    n = 1_000_000
    x = scipy.sparse.csc_matrix((np.ones(3), ([0, 1, 2], [0, 1, 2])), shape=(n, n))
    path = root / "sparse.mat"
    scipy.io.savemat(path, {"X": x})
    cfg = _yaml(root / "mat5.yaml", {"data": {"state": {"variable": "X"}, "time": {"rate": 10}}, **STAGE})
    return path, cfg


def mat5_zlib(root: Path) -> tuple[Path, Path]:
    """A compressed MATLAB v7 file of ~2 MB whose X declares 7×40 doubles and inflates to 2 GB
    (zeros behind its data: a zlib bomb)."""
    import scipy.io
    import writers

    from ccl_cli import simulate as sim

    arm = sim.arm7(seed=0, n_demos=1, n_steps=40)
    path = root / "zlib.mat"
    scipy.io.savemat(path, {"X": arm.X.T}, do_compression=True)
    writers.pad_compressed_mat(path, "X", 2 << 30)
    cfg = _yaml(root / "mat5z.yaml", {"data": {"state": {"variable": "X", "samples": "columns"},
                                               "time": {"rate": 10}}, **STAGE})
    return path, cfg


def one_line_csv(root: Path, gigabytes: float) -> tuple[Path, Path]:
    """A CSV file of one line: a header cell, then numbers, ``gigabytes`` long."""
    path = root / "one_line.csv"
    block = b"1.0," * (1 << 18)
    with open(path, "wb") as f:
        f.write(b"%time,")
        for _ in range(int(gigabytes * 1e9) // len(block)):
            f.write(block)
    cfg = _yaml(root / "csv.yaml", {"data": {"state": {"columns": ["x"]}, "time": {"rate": 10}}, **STAGE})
    return path, cfg


def fifo_cases(root: Path) -> dict[str, list[str]]:
    """Command lines naming FIFOs: given directly, or named by a ROS 2 bag's metadata."""
    import writers

    out: dict[str, list[str]] = {}
    state = {"topic": "/joint_states", "field": "position"}
    cfg = _yaml(root / "bag.yaml", {"data": {"state": state}, **STAGE})
    for suffix in (".csv", ".bag", ".mat", ".h5"):
        fifo = root / f"fifo{suffix}"
        os.mkfifo(fifo)
        out[f"fifo_given{suffix}"] = ["learn-a", fifo, "-o", root / f"o_fifo{suffix}", "-q"]
    rec = writers.joint_recording(n=40)
    for storage in ("sqlite3", "mcap"):
        bag = writers.write_ros2_bag(root / f"bag_{storage}", rec, storage)
        store = next(p for p in bag.iterdir() if p.suffix in (".db3", ".mcap"))
        store.unlink()
        os.mkfifo(store)
        out[f"fifo_in_metadata_{storage}"] = ["learn-a", bag, "-c", cfg, "-o", root / f"o_{storage}", "-q"]
    bag = writers.write_ros2_bag(root / "bag_meta", rec, "sqlite3")
    (bag / "metadata.yaml").unlink()
    os.mkfifo(bag / "metadata.yaml")
    out["fifo_metadata_yaml"] = ["learn-a", bag, "-c", cfg, "-o", root / "o_meta", "-q"]
    out["fifo_metadata_yaml_given"] = ["inspect", bag / "metadata.yaml", "-q"]
    return out


def damaged_models(root: Path, model: Path, n: int = 3, tries: int = 3000) -> list[Path]:
    """Copies of ``model`` with bytes near attribute names damaged until libhdf5 fails while
    iterating an attribute table (the probe of round 2 counted such files as fine): the
    first ``n`` found, with a seeded search."""
    import fuzz

    raw = model.read_bytes()
    rng = random.Random(20)
    found: list[Path] = []
    for _ in range(tries):
        _, damaged = fuzz.damage_attributes(raw, rng)
        path = root / f"damaged_{len(found)}.h5"
        path.write_bytes(damaged)
        if _attribute_iteration_fails(path):
            found.append(path)
            if len(found) == n:
                break
    return found


def _attribute_iteration_fails(path: Path) -> bool:
    """In a child with a 3-s limit: the file opens, and iterating some attribute table raises."""
    code = subprocess.run([sys.executable, "-c", _ITERATE, str(path)], stdin=subprocess.DEVNULL,
                          stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL, timeout=30,
                          preexec_fn=lambda: resource.setrlimit(resource.RLIMIT_CPU, (3, 4))).returncode
    return code == 3


_ITERATE = """
import sys, h5py
try:
    f = h5py.File(sys.argv[1], "r")
except Exception:
    sys.exit(0)
objs = [f]
try:
    f.visititems(lambda n, o: objs.append(o))
except Exception:
    sys.exit(0)
for o in objs:
    try:
        for k in o.attrs:
            o.attrs[k]
    except Exception:
        sys.exit(3)
"""


def round4(root: Path, toy: Path, want: Any) -> dict[str, Any]:
    """The bars of issue 28 (see the module's docstring)."""
    import fuzz
    import writers

    results: dict[str, Any] = {}
    pipeline = _yaml(root / "pipe4.yaml", STAGE)
    if want("dask"):
        recs = root / "recs"
        recs.mkdir()
        from ccl_cli import simulate as sim
        from ccl_cli.io import write_demonstrations

        for i in range(8):
            write_demonstrations(recs / f"rec_{i}.h5", sim.toy2d(constraint="parabola", n_demos=10, seed=i))
        clean = root / "clean"
        run(["batch", "--files", recs / "*.h5", "-c", pipeline, "-o", clean, "-q", "-j", "1"], root,
            timeout=300)
        for victim in ("worker", "scheduler"):
            results[f"dask_{victim}_killed"] = dask_kill(root, recs, pipeline, victim, clean)
    if want("ros1_positions"):
        good = writers.write_ros1_bag(root / "good.bag", writers.joint_recording(n=60, gap_after=30))
        raw = good.read_bytes()
        cfg = _yaml(root / "bag1.yaml", {"data": {"state": {"topic": "/joint_states", "field": "position"},
                                                  "action": {"derive": "state"}}, **STAGE})
        rng, seen = random.Random(28), set()
        for _ in range(400):
            mutation, damaged = fuzz.ros1_positions(raw, rng)
            if mutation in seen:
                continue
            seen.add(mutation)
            path = root / "damaged.bag"
            path.write_bytes(damaged)
            name = mutation.replace("ros1-position:", "ros1_")
            results[f"{name}_learn_a"] = run(["learn-a", path, "-c", cfg, "-o", root / "ob", "-q"], root)
            results[f"{name}_inspect"] = run(["inspect", path, "-q"], root)
    if want("int_5000"):
        cfg = root / "wide_int.yaml"
        cfg.write_text(f"seed: 1\ndata:\n  test:\n    seed: {'9' * 5000}\n")
        results["int_5000_config"] = run(["learn-a", toy, "-c", cfg, "-o", root / "oi", "-q"], root)
    if want("non_utf8_name"):
        odd = root / os.fsdecode(b"rec\xff\xfe.h5")
        shutil.copy(toy, odd)
        results["non_utf8_name_learn_a"] = run(["learn-a", odd, "-o", root / os.fsdecode(b"o\xfc"), "-q"],
                                               root)
        results["non_utf8_name_batch_glob"] = run(["batch", "--files", root / "*.h5", "-c", pipeline, "-o",
                                                   root / "ob4", "-q", "-j", "1"], root, timeout=300)
    if want("key_bomb"):
        bomb = root / "bomb.yaml"
        bomb.write_text("data:\n" + "".join(f"  k{i:06d}: {i}\n" for i in range(200_000)))
        results["key_bomb"] = {"file_bytes": bomb.stat().st_size,
                               **run(["learn-a", toy, "-c", bomb, "-o", root / "ok", "-q"], root)}
    if want("wide_csv"):
        import bench_csv

        config = bench_csv.wide_csv(root / "wide.csv", 128.0)
        results["wide_csv_learn_a"] = {"file_bytes": (root / "wide.csv").stat().st_size,
                                       **run(["learn-a", root / "wide.csv", "-c", config, "-o", root / "ow",
                                              "-q", "--test-fraction", "0"], root, timeout=300)}
        results["wide_csv_inspect"] = run(["inspect", root / "wide.csv", "-q"], root, timeout=300)
        (root / "wide.csv").unlink()
    if want("force_look_alike"):
        mine = root / "results"
        mine.mkdir()
        files = {"run.json": json.dumps({"command": "my-tool", "versions": {"my-tool": "1"}}),
                 "notes.md": "mine"}
        for name, text in files.items():
            (mine / name).write_text(text)
        res = run(["learn-a", toy, "-o", mine, "--force", "-q"], root)
        results["force_look_alike"] = {**res, "files_intact": {p.name: p.read_text() for p in mine.iterdir()}
                                       == files}
    return results


def dask_kill(root: Path, recs: Path, pipeline: Path, victim: str, clean: Path) -> dict[str, Any]:
    """``ccl batch --scheduler`` on a cluster of one worker (no nanny: nothing restarts it);
    the worker or the scheduler SIGKILLed once two jobs are written; then a local rerun."""
    import dask_cluster

    out = root / f"dask_{victim}"
    cluster, info = dask_cluster.start(1, nanny=False)
    err = root / ".dask_stderr"
    try:
        with open(err, "wb") as e:
            proc = subprocess.Popen([*CCL, "batch", "--files", str(recs / "*.h5"), "-c", str(pipeline), "-o",
                                     str(out), "--scheduler", info["address"]], cwd=root,
                                    stdout=subprocess.DEVNULL, stderr=e)
            deadline = time.monotonic() + 300
            while time.monotonic() < deadline and proc.poll() is None and not (
                    (out / "jobs").exists() and len([p for p in (out / "jobs").iterdir()
                                                     if not p.name.startswith(".")]) >= 2):
                time.sleep(0.02)
            pid = info["scheduler_pid"] if victim == "scheduler" else next(iter(info["workers"].values()))
            os.kill(pid, signal.SIGKILL)
            killed = time.monotonic()
            try:
                code = proc.wait(timeout=120)
            except subprocess.TimeoutExpired:
                proc.kill()
                code = None
            seconds = time.monotonic() - killed
    finally:
        dask_cluster.stop(cluster)
    lines = [ln for ln in err.read_text(errors="replace").splitlines() if ln.strip()]
    rerun = run(["batch", "--files", recs / "*.h5", "-c", pipeline, "-o", out, "-q", "-j", "1"], root,
                timeout=300)
    same = _metrics(out) == _metrics(clean)
    return {"exit": code, "seconds_after_kill": round(seconds, 2), "stderr_lines": len(lines),
            "traceback": any("Traceback" in ln for ln in lines),
            "first_line": lines[0][:300] if lines else "",
            "rerun_exit": rerun["exit"], "rerun_metrics_identical_to_clean_local": same}


def _metrics(out: Path) -> dict[str, Any]:
    """Per job folder, every metric value of its metrics.json (train and test splits)."""
    found = {}
    for p in sorted((out / "jobs").iterdir()):
        if not p.name.startswith("."):
            stages = json.loads((p / "metrics.json").read_text())
            found[p.name] = {(s, split, m): v["value"] for s, e in stages.items()
                             for split in ("train", "test") for m, v in (e.get(split) or {}).items()}
    return found


def leftovers(folder: Path, keep: set[str]) -> list[str]:
    return sorted(p.name for p in folder.iterdir() if p.name not in keep)


# -- the cases -----------------------------------------------------------------------------------
def measure(only: set[str] | None, gigabytes: float) -> dict[str, Any]:
    from ccl_cli import simulate as sim
    from ccl_cli.io import write_demonstrations

    root = Path(tempfile.mkdtemp(prefix="ccl-bars-"))
    results: dict[str, Any] = {}

    def want(name: str) -> bool:
        return only is None or any(name.startswith(o) for o in only)

    try:
        toy = root / "toy.h5"
        write_demonstrations(toy, sim.toy2d(n_demos=6, n_steps=40, seed=0))
        for name, build in (("mat73_bomb", mat73_bomb), ("mat5_sparse", mat5_sparse),
                            ("mat5_zlib", mat5_zlib)):
            if want(name):
                path, cfg = build(root)
                results[name] = {"file_bytes": path.stat().st_size,
                                 **run(["learn-a", path, "-c", cfg, "-o", root / f"o_{name}", "-q"], root)}
        if want("csv_one_line"):
            path, cfg = one_line_csv(root, gigabytes)
            results["csv_one_line"] = {"file_bytes": path.stat().st_size,
                                       **run(["learn-a", path, "-c", cfg, "-o", root / "o3", "-q"], root,
                                             timeout=120)}
            path.unlink()
        if want("fifo"):
            for name, argv in fifo_cases(root).items():
                results[name] = run(argv, root, timeout=20)
        pipeline = _yaml(root / "pipe.yaml", STAGE)
        if want("batch_user_dir"):
            user = root / "user"
            user.mkdir()
            for name in ("summary.md", "summary.csv", "summary.json", "summary.png", "notes.txt"):
                (user / name).write_text(f"the user's {name}\n")
            before = {p.name: p.read_bytes() for p in user.iterdir()}
            res = run(["batch", "--files", toy, "-c", pipeline, "-o", user, "-q", "-j", "1"], root,
                      timeout=120)
            after = {p.name: p.read_bytes() for p in user.iterdir() if p.is_file()}
            intact = all(after.get(k) == v for k, v in before.items())
            results["batch_user_dir"] = {**res, "files_intact": intact,
                                         "added": sorted({p.name for p in user.iterdir()} - set(before))}
        if want("batch_read_only_parent"):
            ro = root / "ro"
            ro.mkdir()
            ro.chmod(0o555)
            prefix = []
            if os.geteuid() == 0 and shutil.which("setpriv"):
                prefix = [shutil.which("setpriv"), "--bounding-set=-dac_override,-dac_read_search",
                          "--inh-caps=-all", "--"]
            try:
                res = run(["batch", "--files", toy, "-c", pipeline, "-o", ro / "out", "-q", "-j", "1"], root,
                          timeout=120, prefix=prefix)
            finally:
                ro.chmod(0o755)
            results["batch_read_only_parent"] = {**res, "left": sorted(p.name for p in ro.iterdir())}
        if want("ulimit"):
            def limit() -> None:
                resource.setrlimit(resource.RLIMIT_FSIZE, (8192, 8192))  # ulimit -f 8

            for name, argv in (("ulimit_learn_a", ["learn-a", toy, "-o", "out_u", "-q"]),
                               ("ulimit_learn_a_plots", ["learn-v", toy, "-o", "out_v", "-q",
                                                         "--n-centres", "4"]),
                               ("ulimit_batch", ["batch", "--files", toy, "-c", pipeline, "-o", "batch_u",
                                                 "-q", "-j", "1"])):
                work = root / name
                work.mkdir()
                res = run(argv, work, timeout=300, preexec=limit)
                results[name] = {**res, "left": leftovers(work, set())}
        results.update(round4(root, toy, want))
        if want("damaged_model"):
            assert run(["learn-v", toy, "-o", root / "v", "-q", "--n-centres", "4", "--test-fraction", "0"],
                       root, timeout=300)["exit"] == 0
            for k, path in enumerate(damaged_models(root, root / "v" / "model.h5")):
                results[f"damaged_model_{k}_predict"] = run(["predict", path, toy, "-o", root / f"p{k}.csv",
                                                             "-q"], root, timeout=120)
                results[f"damaged_model_{k}_inspect"] = run(["inspect", path, "-q"], root, timeout=120)
    finally:
        shutil.rmtree(root, ignore_errors=True)
    return results


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--only", default=None, help="comma-separated case name prefixes")
    ap.add_argument("--big-csv-gb", type=float, default=2.0, help="size of the one-line CSV")
    args = ap.parse_args()
    only = set(args.only.split(",")) if args.only else None
    cases = measure(only, args.big_csv_gb)
    sys.stdout.write(json.dumps({"benchmark": "hostile_bars", "cases": cases}) + "\n")


if __name__ == "__main__":
    main()
