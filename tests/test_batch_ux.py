"""What ``ccl batch`` says: -j capped at the usable cores with one line (more only with
--oversubscribe), and each job's warnings named by the job."""

import json
import os
import subprocess
from pathlib import Path

import numpy as np
from tests_paths import CCL

from ccl_cli.app.batch import worker_count
from ccl_cli.learn.blas import affinity_cores


def _recordings(folder: Path, n: int) -> list[Path]:
    rng = np.random.default_rng(1)
    folder.mkdir()
    out = []
    for k in range(n):
        s = np.linspace(0, 0.4, 150)
        X = np.c_[s, 0.5 * s, 0 * s + 0.1 * k] + rng.normal(0, 1e-4, (150, 3))
        out.append(folder / f"run{k}.txt")
        np.savetxt(out[-1], X)
    return out


def test_workers_are_at_most_the_usable_cores_unless_oversubscribed():
    cores = affinity_cores()
    assert cores == len(os.sched_getaffinity(0))
    assert worker_count(None) == (cores, None)
    n, said = worker_count(1000)
    assert n == cores and said.startswith(f"-j 1000: {cores} usable core") and "--oversubscribe" in said
    assert worker_count(1000, oversubscribe=True) == (1000, None)
    assert worker_count(1000, jobs=1) == (1, worker_count(1000)[1])  # never more workers than jobs
    assert worker_count(1) == (1, None)


def test_batch_caps_j_and_names_the_job_of_each_warning(tmp_path):
    files = _recordings(tmp_path / "logs", 3)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {state: {columns: [0, 1, 2]}, action: {derive: state}, time: {rate: 20}}\n"
                   "output: {plots: false}\nstages: [learn-a]\n")
    done = subprocess.run([CCL, "batch", "--files", *map(str, files), "-c", str(cfg), "-o",
                           str(tmp_path / "out"), "-j", "1000", "--json"], capture_output=True, text=True,
                          timeout=600)
    assert done.returncode == 0, done.stderr
    cores = affinity_cores()
    summary = json.loads(done.stdout)
    assert summary["ok"] == 3 and summary["workers"] == min(cores, 3)
    lines = done.stderr.splitlines()
    assert [ln for ln in lines if "usable core" in ln] == [
        f"ccl: -j 1000: {cores} usable core{'s' if cores != 1 else ''}, so {cores} worker"
        f"{'s' if cores != 1 else ''} (more would only share them; --oversubscribe starts 1000)"]
    jobs = sorted(p.name for p in (tmp_path / "out" / "jobs").iterdir())
    assert [j.split("-")[0] for j in jobs] == ["run0_txt", "run1_txt", "run2_txt"]
    for job in jobs:  # each job's few-demonstrations warning, named by its job
        assert any(ln.startswith(f"ccl: {job}: warning: only 1 demonstration") for ln in lines), done.stderr
    assert not any(ln.startswith("warning:") for ln in lines)


def test_batch_refuses_a_recording_given_twice(tmp_path):
    files = _recordings(tmp_path / "logs", 2)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {state: {columns: [0, 1, 2]}, action: {derive: state}, time: {rate: 20}}\n"
                   "stages: [learn-a]\n")
    out = tmp_path / "out"
    args = ["batch", "--files", str(files[0]), str(tmp_path / "logs"), "-c", str(cfg), "-o", str(out)]
    done = subprocess.run([CCL, *args], capture_output=True, text=True, timeout=300)
    assert done.returncode == 2 and not (tmp_path / "out").exists()
    assert done.stderr.strip() == f"ccl: error: {files[0]} is given twice: it would be run twice, into one " \
                                  "folder; give each once"
