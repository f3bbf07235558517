"""ccl batch: parallel runs over many recordings, locally and on Dask, resumable."""

import json
import os
import re
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import write_demonstrations

CCL = shutil.which("ccl") or str(Path(sys.executable).parent / "ccl")
CONFIG = """
data:
  test: {fraction: 0.3, seed: 0}
learn-a:
  method: linear
  regressors: polynomial
  degree: 1
stages:
  - learn-a
output: {plots: false}
"""
N_GOOD = 20


@pytest.fixture(scope="module")
def recordings(tmp_path_factory):
    root = tmp_path_factory.mktemp("recs")
    for i in range(N_GOOD):
        write_demonstrations(root / f"rec_{i:02d}.h5", sim.toy2d(constraint="parabola", n_demos=10, seed=i))
    (root / "rec_bad1.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 64)  # corrupt HDF5
    nan = sim.toy2d(n_demos=3, seed=99)
    nan.U[4, 0] = float("nan")
    write_demonstrations(root / "rec_bad2.h5", nan)  # NaN actions
    cfg = root / "pipeline.yaml"
    cfg.write_text(CONFIG)
    return root


def batch(capsys, *args):
    code = main(["batch", *map(str, args), "--json", "-q"])
    out = capsys.readouterr()
    return code, json.loads(out.out) if out.out.strip() else None, out.err


def job_metrics(out: Path) -> dict[str, dict]:
    res = {}
    for d in (out / "jobs").iterdir():
        if not d.name.startswith("."):
            res[d.name] = json.loads((d / "metrics.json").read_text())
    return res


def values(metrics: dict) -> dict:
    return {(s, p, m): v["value"] for s, e in metrics.items() for p in ("train", "test")
            for m, v in (e.get(p) or {}).items()}


def test_local_batch_reports_failures_and_matches_ccl_run(capsys, recordings, tmp_path):
    out = tmp_path / "local"
    code, summary, _ = batch(capsys, "--files", recordings / "rec_*.h5", "-c", recordings / "pipeline.yaml",
                             "-o", out, "--workers", 2)
    assert code == 1
    assert summary["jobs"] == N_GOOD + 2 and summary["ok"] == N_GOOD and summary["failed"] == 2
    errors = {Path(f["files"][0]).name: f["error"] for f in summary["failures"]}
    assert set(errors) == {"rec_bad1.h5", "rec_bad2.h5"}
    assert "rec_bad1.h5" in errors["rec_bad1.h5"] and "cannot" in errors["rec_bad1.h5"]
    assert "non-finite" in errors["rec_bad2.h5"]
    rows = (out / "summary.csv").read_text().splitlines()
    assert len(rows) == N_GOOD + 3 and rows[0].startswith("job,files,method,n_constraints,status,seconds")
    assert "## Failures" in (out / "summary.md").read_text()
    assert not (out / "summary.png").exists()  # output.plots is false: no job draws figures
    # the same per-file metrics as ccl run on each file alone
    per_job = job_metrics(out)
    for i in (0, 7, 19):
        alone = tmp_path / f"alone_{i}"
        assert main(["run", str(recordings / "pipeline.yaml"), "--data", str(recordings / f"rec_{i:02d}.h5"),
                     "-o", str(alone), "-q"]) == 0
        capsys.readouterr()
        job = next(k for k in per_job if k.startswith(f"rec_{i:02d}_h5-"))
        assert values(per_job[job]) == values(json.loads((alone / "metrics.json").read_text()))


def test_dask_cluster_gives_the_same_metrics(capsys, recordings, tmp_path):
    from distributed import LocalCluster

    local, remote = tmp_path / "local", tmp_path / "dask"
    code, summary, _ = batch(capsys, "--files", recordings / "rec_0*.h5", "-c", recordings / "pipeline.yaml",
                             "-o", local, "-j", 2)
    assert code == 0, summary["failures"]
    with LocalCluster(n_workers=2, threads_per_worker=1, processes=True, host="127.0.0.1",
                      dashboard_address=None) as cluster:
        code, summary, _ = batch(capsys, "--files", recordings / "rec_0*.h5", "-c",
                                 recordings / "pipeline.yaml", "-o", remote, "--scheduler",
                                 cluster.scheduler_address)
    assert code == 0 and summary["ok"] == 10
    a, b = job_metrics(local), job_metrics(remote)
    assert a.keys() == b.keys()
    assert all(values(a[k]) == values(b[k]) for k in a)


def test_fork_server_workers_give_the_same_metrics(capsys, recordings, tmp_path, monkeypatch):
    """Where workers may not fork from ccl (another thread runs, or not Linux) they fork
    from a fork server: the same jobs, the same numbers."""
    import ccl_cli.app.batch as batch_module

    forked, served = tmp_path / "forked", tmp_path / "served"
    args = ["--files", recordings / "rec_0*.h5", "-c", recordings / "pipeline.yaml", "-j", 2]
    code, summary, err = batch(capsys, *args, "-o", forked)
    assert code == 0 and summary["ok"] == 10, err
    monkeypatch.setattr(batch_module, "can_fork", lambda: False)
    code, summary, err = batch(capsys, *args, "-o", served)
    assert code == 0 and summary["ok"] == 10, err
    a, b = job_metrics(forked), job_metrics(served)
    assert a.keys() == b.keys() and all(values(a[k]) == values(b[k]) for k in a)


def test_bad_scheduler_and_manifest_are_usage_errors(capsys, recordings, tmp_path):
    code, _, err = batch(capsys, "--files", recordings / "rec_00.h5", "-c", recordings / "pipeline.yaml",
                         "-o", tmp_path / "x", "--scheduler", "tcp://127.0.0.1:9")
    assert code == 2 and "cannot connect to the Dask scheduler" in err
    bad = tmp_path / "m.yaml"
    bad.write_text("jobs:\n  - files: [nothing_*.h5]\n    config: pipeline.yaml\n")
    code, _, err = batch(capsys, bad, "-o", tmp_path / "y")
    assert code == 2 and "no files match" in err


def test_manifest_rules_overrides_and_groups(capsys, recordings, tmp_path):
    manifest = tmp_path / "batch.yaml"
    manifest.write_text(f"""
out: out
jobs:
  - files: ["{recordings}/rec_0[0-2].h5"]
    config: {recordings}/pipeline.yaml
  - files: ["{recordings}/rec_1[0-1].h5"]
    config: {recordings}/pipeline.yaml
    group: true
    overrides: {{learn-a: {{method: nhat}}}}
overrides:
  "{recordings}/rec_01.h5": {{learn-a: {{n_constraints: 1, selection: eigengap}}}}
""")
    code, summary, err = batch(capsys, manifest, "-j", 2, "--allow-outside")  # the recordings: elsewhere
    assert code == 0, err
    assert summary["ok"] == 4  # three single-file jobs and one group of two
    rows = {r["job_id"]: r for r in summary_results(tmp_path / "out")}
    group = next(r for k, r in rows.items() if k.startswith("group_"))
    assert len(group["files"]) == 2 and group["stages"]["learn-a"]["method"] == "nhat"
    one = next(r for k, r in rows.items() if k.startswith("rec_01_h5"))
    cfg = json.loads((tmp_path / "out" / "jobs" / one["job_id"] / "run.json").read_text())["config"]
    assert cfg["learn-a"]["n_constraints"] == 1


def summary_results(out: Path) -> list[dict]:
    return json.loads((out / "summary.json").read_text())["results"]


def test_resume_after_kill(recordings, tmp_path):
    out = tmp_path / "resume"
    args = [CCL, "batch", "--files", str(recordings / "rec_*.h5"), "-c", str(recordings / "pipeline.yaml"),
            "-o", str(out), "-j", "1", "-q"]
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, start_new_session=True)
    jobs = out / "jobs"
    deadline = time.time() + 120
    while time.time() < deadline:
        done = [p for p in jobs.iterdir() if not p.name.startswith(".")] if jobs.exists() else []
        if len(done) >= 3:
            break
        time.sleep(0.05)
    os.killpg(proc.pid, signal.SIGKILL)  # the batch and its worker processes, mid-way
    proc.wait()
    time.sleep(0.2)
    finished = {p.name for p in jobs.iterdir() if not p.name.startswith(".")}
    assert 3 <= len(finished) < N_GOOD
    for name in finished:  # never a half-written job folder
        assert (jobs / name / "metrics.json").exists() and (jobs / name / "job.json").exists()
    again = subprocess.run([*args, "--json"], capture_output=True, text=True)
    summary = json.loads(again.stdout)
    assert again.returncode == 1  # the two bad files
    assert summary["skipped"] == len(finished)
    assert summary["ok"] == N_GOOD - len(finished)
    assert not [p for p in jobs.iterdir() if p.name.startswith(".")]  # stale temp folders removed
    # a third run skips everything that succeeded; --force re-runs
    third = json.loads(subprocess.run([*args, "--json"], capture_output=True, text=True).stdout)
    assert third["skipped"] == N_GOOD and third["ok"] == 0


def _session(sid: int) -> list[tuple[int, str]]:
    """Processes of session ``sid`` (the batch and everything it started)."""
    out = []
    for d in os.listdir("/proc"):
        if d.isdigit():
            try:
                fields = Path(f"/proc/{d}/stat").read_text().rsplit(")", 1)[1].split()
                if int(fields[3]) == sid and fields[0] != "Z":
                    out.append((int(d), Path(f"/proc/{d}/cmdline").read_text().replace("\0", " ")[:80]))
            except (OSError, IndexError, ValueError):
                pass
    return out


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_sigkill_of_a_two_worker_batch_leaves_no_process(recordings, tmp_path):
    out = tmp_path / "killed"
    args = [CCL, "batch", "--files", str(recordings / "rec_0*.h5"), "-c", str(recordings / "pipeline.yaml"),
            "-o", str(out), "-j", "2", "-q"]
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, start_new_session=True)
    deadline = time.time() + 120
    # ccl and 2 workers forked from it (or from a fork server: then also the server and a tracker)
    while time.time() < deadline and len(_session(proc.pid)) < 3:
        time.sleep(0.05)
    assert len(_session(proc.pid)) >= 3, _session(proc.pid)
    os.kill(proc.pid, signal.SIGKILL)  # ccl alone: its children must follow
    proc.wait()
    deadline = time.time() + 15
    while time.time() < deadline and _session(proc.pid):
        time.sleep(0.1)
    assert _session(proc.pid) == []
    again = subprocess.run([*args, "--json"], capture_output=True, text=True, timeout=600)
    summary = json.loads(again.stdout)
    assert again.returncode == 0 and summary["ok"] + summary["skipped"] == 10
    assert not [p for p in (out / "jobs").iterdir() if p.name.startswith(".")]


def test_resume_does_not_depend_on_how_the_manifest_is_spelled(capsys, recordings, tmp_path, monkeypatch):
    manifest = tmp_path / "m.yaml"
    shutil.copy(recordings / "pipeline.yaml", tmp_path / "pipeline.yaml")
    for i in range(3):
        shutil.copy(recordings / f"rec_{i:02d}.h5", tmp_path / f"rec_{i:02d}.h5")
    manifest.write_text("out: out\njobs:\n  - files: [rec_0*.h5]\n    config: pipeline.yaml\n")
    code, summary, err = batch(capsys, manifest.resolve(), "-j", 1)
    assert code == 0 and summary["ok"] == 3, err
    monkeypatch.chdir(tmp_path)
    code, summary, err = batch(capsys, "m.yaml", "-j", 1)
    assert code == 0 and summary["skipped"] == 3 and summary["ok"] == 0, err
    monkeypatch.chdir(tmp_path.parent)
    code, summary, err = batch(capsys, Path(tmp_path.name) / ".." / tmp_path.name / "m.yaml", "-j", 1)
    assert code == 0 and summary["skipped"] == 3, err
    assert len(list((tmp_path / "out" / "jobs").iterdir())) == 3


@pytest.mark.parametrize("text,match", [
    ("jobs:\n  - files: 3\n", r"jobs\[0\].files must be a path/glob"),
    ("jobs:\n  - files: [a.h5, 2.5]\n", r"jobs\[0\].files must be"),
    ("jobs:\n  - {files: x.h5, config: [a]}\n", r"jobs\[0\].config must be a file path"),
    ("jobs:\n  - {files: x.h5, group: 'yes'}\n", r"jobs\[0\].group must be true or false"),
    ("jobs:\n  - {files: x.h5, overrides: [1]}\n", r"jobs\[0\].overrides must be a mapping"),
    ("out: [1]\njobs: []\n", "out must be a folder path"),
    ("jobs: []\noverrides: [1, 2]\n", "overrides must map file paths"),
    ("jobs: {a: 1}\n", "needs a jobs: list"),
    ("jobs:\n  - &a [*a]\n", "alias refers to its own parent"),
])
def test_manifest_fields_are_typed(capsys, tmp_path, text, match):
    manifest = tmp_path / "m.yaml"
    manifest.write_text(text)
    code, _, err = batch(capsys, manifest, "-o", tmp_path / "o")
    assert code == 2 and re.search(match, err) and err.count("\n") == 1, err


def test_override_keys_of_several_types_are_one_line(capsys, recordings, tmp_path):
    """A manifest's overrides with an integer key beside string ones (YAML ``1:``): one line
    naming the key (json could not sort the keys: an internal TypeError, fuzz seed 280)."""
    shutil.copy(recordings / "rec_00.h5", tmp_path / "rec_00.h5")
    shutil.copy(recordings / "pipeline.yaml", tmp_path / "pipeline.yaml")
    manifest = tmp_path / "m.yaml"
    manifest.write_text("jobs:\n  - files: rec_00.h5\n    config: pipeline.yaml\n"
                        "    overrides: {learn-a: {n_constraints: 1, 1: x}}\n")
    code, _, err = batch(capsys, manifest, "-o", tmp_path / "o")
    assert code == 2 and "jobs[0]" in err and "learn-a" in err and err.count("\n") == 1, err


def test_batch_never_writes_into_a_users_folder(capsys, recordings, tmp_path):
    """-o on a folder with the user's files (even ones named like the summaries): exit 2,
    every file as it was; an empty folder, or one ccl made, is written into."""
    user = tmp_path / "user"
    user.mkdir()
    mine = {name: f"my {name}\n".encode() for name in ("summary.md", "summary.csv", "summary.json",
                                                       "summary.png", "notes.txt")}
    for name, raw in mine.items():
        (user / name).write_bytes(raw)
    one = ["--files", recordings / "rec_00.h5", "-c", recordings / "pipeline.yaml", "-j", 1]
    code, _, err = batch(capsys, *one, "-o", user)
    assert code == 2 and "holds files ccl did not write" in err and err.count("\n") == 1, err
    assert {p.name: p.read_bytes() for p in user.iterdir()} == mine
    empty = tmp_path / "empty"
    empty.mkdir()
    code, summary, err = batch(capsys, *one, "-o", empty)
    assert code == 0 and summary["ok"] == 1 and (empty / ".ccl-output").is_file(), err
    code, summary, err = batch(capsys, *one, "-o", empty)  # ccl's own folder: resumed
    assert code == 0 and summary["skipped"] == 1, err


@pytest.mark.parametrize("edit", ["dotdot", "symlink", "out", "config"])
def test_manifest_paths_stay_in_its_folder(capsys, recordings, tmp_path, edit):
    """Paths a manifest names lead inside its folder (.., symlinks resolved), unless
    --allow-outside: nothing is written outside."""
    here = tmp_path / "project"
    here.mkdir()
    shutil.copy(recordings / "pipeline.yaml", here / "pipeline.yaml")
    shutil.copy(recordings / "rec_00.h5", here / "rec_00.h5")
    files, config, out = "[rec_00.h5]", "pipeline.yaml", "out"
    if edit == "dotdot":
        files = f"[{os.path.relpath(recordings / 'rec_00.h5', here)}]"
    elif edit == "symlink":
        (here / "data").symlink_to(recordings)
        files = "[data/rec_0*.h5]"
    elif edit == "out":
        out = "../escaped"
    else:
        config = os.path.relpath(recordings / "pipeline.yaml", here)
    manifest = here / "m.yaml"
    manifest.write_text(f"out: {out}\njobs:\n  - files: {files}\n    config: {config}\n")
    before = sorted(p.name for p in tmp_path.iterdir())
    code, _, err = batch(capsys, manifest, "-j", 1)
    assert code == 2 and "outside" in err and "--allow-outside allows it" in err and err.count("\n") == 1, err
    assert sorted(p.name for p in tmp_path.iterdir()) == before and not (here / "out").exists()
    code, summary, err = batch(capsys, manifest, "-j", 1, "--allow-outside")
    assert code == 0 and summary["ok"] >= 1, err


def test_batch_folder_of_an_earlier_version_is_refused_with_a_hint(capsys, recordings, tmp_path):
    """A batch folder without the .ccl-output marker (as a ccl before the marker left it, or
    anything made to look like one: jobs/ and summaries, run.json files) is not ccl's: refused
    untouched, with a one-line hint to remove it; with the marker it is resumed."""
    out = tmp_path / "old"
    one = ["--files", recordings / "rec_00.h5", "-c", recordings / "pipeline.yaml", "-j", 1, "-o", out]
    code, summary, err = batch(capsys, *one)
    assert code == 0 and summary["ok"] == 1, err
    code, summary, err = batch(capsys, *one)  # marked: resumed
    assert code == 0 and summary["skipped"] == 1, err
    (out / ".ccl-output").unlink()  # as an earlier version left it
    before = sorted(str(p) for p in out.rglob("*"))
    code, _, err = batch(capsys, *one)
    assert code == 2 and err.count("\n") == 1 and "holds files ccl did not write" in err
    assert "the batch folder of an earlier ccl" in err and "remove it yourself" in err
    assert sorted(str(p) for p in out.rglob("*")) == before
    (out / ".ccl-output").write_text('{"written_by": "someone"}')  # a look-alike marker
    code, _, err = batch(capsys, *one)
    assert code == 2 and "holds files ccl did not write" in err


def test_summary_figure_names_each_job_without_its_key_hash():
    from ccl_cli.render.summary import _short

    assert _short("toy2d_ncl_h5-67f8dc25") == "toy2d_ncl_h5"
    assert _short("a_very_long_recording_name_of_a_kuka_log_bag-0123abcd") == "a_very_long_recording_n…"
    assert _short("plain-name") == "plain-name"


def test_summary_figure_is_drawn_when_a_job_draws_figures(capsys, recordings, tmp_path):
    """summary.png: one panel per held-out metric, 80 dpi, a row per job (as tall as the jobs
    need); drawn only when a job's config draws figures (an earlier one is removed when not)."""
    from PIL import Image

    from ccl_cli.app.batch import JobResult
    from ccl_cli.render.summary import write_summary

    out = tmp_path / "fig"
    code, summary, err = batch(capsys, "--files", recordings / "rec_0*.h5", "-c",
                               recordings / "pipeline.yaml", "-o", out, "-j", 1)
    assert code == 0, err
    results = [JobResult(**r) for r in summary_results(out)]
    metrics = {k for r in results for k, v in r.stages["learn-a"]["test"].items() if v > 0}
    write_summary(out, results, 1.0, plots=True)
    from ccl_cli.render import jobs_figure as jf

    with Image.open(out / "summary.png") as png:
        assert png.size[1] == round((jf.HEAD + 10 * jf.ROW + jf.FOOT) * jf.DPI)
        assert png.size[0] > round(jf.PANEL * len(metrics) * jf.DPI)
    assert "(summary.png)" in (out / "summary.md").read_text()
    write_summary(out, results, 1.0, plots=False)
    assert not (out / "summary.png").exists() and "summary.png" not in (out / "summary.md").read_text()


@pytest.mark.skipif(not Path("/proc/self/stat").exists(), reason="needs /proc")
def test_ctrl_c_of_a_running_batch_leaves_no_temporary_and_no_process(recordings, tmp_path):
    """SIGINT while two workers write job folders (figures on: each job takes a while):
    exit 130 with one line, no temporary folder, no process left; a rerun resumes."""
    cfg = tmp_path / "plots.yaml"
    cfg.write_text(CONFIG.replace("plots: false", "plots: true"))
    out = tmp_path / "interrupted"
    args = [CCL, "batch", "--files", str(recordings / "rec_0*.h5"), "-c", str(cfg), "-o", str(out), "-j", "2",
            "-q"]
    proc = subprocess.Popen(args, stderr=subprocess.PIPE, text=True, start_new_session=True)
    jobs = out / "jobs"
    deadline = time.time() + 120
    while time.time() < deadline and (not jobs.exists() or len([p for p in jobs.iterdir()
                                                                  if not p.name.startswith(".")]) < 2):
        time.sleep(0.02)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    assert proc.returncode == 130, err
    assert [ln for ln in err.splitlines() if ln.startswith("ccl: ") and "warning" not in ln] == \
        ["ccl: interrupted; no partial outputs were left"]
    assert [p.name for p in jobs.iterdir() if p.name.startswith(".")] == []
    deadline = time.time() + 15
    while time.time() < deadline and _session(proc.pid):
        time.sleep(0.1)
    assert _session(proc.pid) == []
    finished = [p for p in jobs.iterdir()]
    assert 2 <= len(finished) < 10 and all((p / "job.json").exists() for p in finished)
    again = subprocess.run([*args, "--json"], capture_output=True, text=True, timeout=600)
    summary = json.loads(again.stdout)
    assert again.returncode == 0
    assert summary["skipped"] == len(finished) and summary["ok"] == 10 - len(finished)


def test_forked_workers_get_their_share_of_the_blas_threads():
    """Workers forked from ccl run cores / workers BLAS threads each (as the fork server's
    environment gave them), whatever ccl's own BLAS started with."""
    code = ("from ccl_cli.app.batch import can_fork, fork_workers\nfrom ccl_cli.learn import blas\n"
            "assert can_fork()\npool = fork_workers(2)\n"
            "print(sorted({pool.submit(blas.current).result() for _ in range(6)}))\npool.shutdown()\n")
    env = {k: v for k, v in os.environ.items() if k not in ("OMP_NUM_THREADS", "OPENBLAS_NUM_THREADS",
                                                            "MKL_NUM_THREADS")}
    proc = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, env=env, timeout=120)
    assert proc.returncode == 0, proc.stderr
    from ccl_cli.learn import blas

    if blas.controllable():
        assert json.loads(proc.stdout) == [max(1, (os.cpu_count() or 1) // 2)]


# -- a Dask cluster losing workers or its scheduler (os.kill of their pids) ---------------------
def _ccl_lines(err: str) -> list[str]:
    return [ln for ln in err.splitlines() if ln.startswith("ccl: ")]


def _wait_for_jobs(jobs: Path, n: int, proc: subprocess.Popen, timeout: float = 120) -> None:
    """Until ``n`` job folders are written (or the batch has ended)."""
    deadline = time.time() + timeout
    while time.time() < deadline and proc.poll() is None:
        if jobs.exists() and len([p for p in jobs.iterdir() if not p.name.startswith(".")]) >= n:
            return
        time.sleep(0.02)


@pytest.fixture(scope="module")
def clean_local(recordings, tmp_path_factory):
    """The ten rec_0* jobs run locally, once: the metrics every Dask rerun must give."""
    out = tmp_path_factory.mktemp("clean") / "out"
    proc = subprocess.run([CCL, "batch", "--files", str(recordings / "rec_0*.h5"), "-c",
                           str(recordings / "pipeline.yaml"), "-o", str(out), "-j", "2", "-q"],
                          capture_output=True, text=True, timeout=600)
    assert proc.returncode == 0, proc.stderr
    return job_metrics(out)


@pytest.mark.parametrize("victim", ["worker", "scheduler"])
def test_dask_batch_survives_a_killed_worker_or_scheduler(recordings, tmp_path, clean_local, victim):
    """The only worker (nothing restarts it) or the scheduler SIGKILLed mid-batch: ccl ends
    within seconds (no hang), exit 1, one line naming what was lost (the worker and the jobs
    it held; the scheduler), no traceback; a rerun (here: local) completes with the metrics of
    a clean local run."""
    import dask_cluster

    cluster, info = dask_cluster.start(1, nanny=False)
    out = tmp_path / "out"
    args = [CCL, "batch", "--files", str(recordings / "rec_0*.h5"), "-c", str(recordings / "pipeline.yaml"),
            "-o", str(out)]
    try:
        proc = subprocess.Popen([*args, "--scheduler", info["address"], "--worker-wait", "2"],
                                stderr=subprocess.PIPE, stdout=subprocess.DEVNULL, text=True)
        _wait_for_jobs(out / "jobs", 2, proc)
        assert proc.poll() is None, proc.communicate()[1]
        (worker, pid), = info["workers"].items()
        os.kill(info["scheduler_pid"] if victim == "scheduler" else pid, signal.SIGKILL)
        _, err = proc.communicate(timeout=60)  # a hang fails here
    finally:
        dask_cluster.stop(cluster)
    lines = _ccl_lines(err)
    assert proc.returncode == 1 and len(lines) == 1 and "Traceback" not in err, err
    finished = {p.name for p in (out / "jobs").iterdir() if not p.name.startswith(".")}
    assert 2 <= len(finished) < 10
    if victim == "worker":
        named = re.findall(r"rec_0\d_h5-[0-9a-f]{8}", lines[0])
        assert lines[0].startswith(f"ccl: error: no Dask worker left: worker {worker} lost while running job")
        # jobs it held (one may have written its folder before its result reached ccl)
        assert set(named) - finished, lines[0]
        done, left = map(int, re.search(r"(\d+) of 10 jobs done, (\d+) not", lines[0]).groups())
        assert done + left == 10 and done <= len(finished)
    else:
        assert lines[0].startswith(f"ccl: error: lost the Dask scheduler at {info['address']}")
    assert "run the batch again to resume" in lines[0]
    again = subprocess.run([*args, "-j", "2", "-q", "--json"], capture_output=True, text=True, timeout=600)
    summary = json.loads(again.stdout)
    assert again.returncode == 0 and summary["skipped"] >= len(finished), again.stderr
    assert summary["ok"] + summary["skipped"] == 10
    assert not [p for p in (out / "jobs").iterdir() if p.name.startswith(".")]
    now = job_metrics(out)
    assert now.keys() == clean_local.keys() and all(values(now[k]) == values(clean_local[k]) for k in now)


def test_dask_worker_restarted_by_its_nanny_costs_nothing(capsys, recordings, tmp_path, clean_local):
    """A worker killed mid-batch and restarted by its nanny: the jobs it held run again on
    the new worker, one warning line names the lost worker and jobs, every job finishes
    with the metrics of a local run."""
    import dask_cluster

    cluster, info = dask_cluster.start(1, nanny=True)
    out = tmp_path / "out"
    try:
        proc = subprocess.Popen([CCL, "batch", "--files", str(recordings / "rec_0*.h5"), "-c",
                                 str(recordings / "pipeline.yaml"), "-o", str(out), "--scheduler",
                                 info["address"], "--json"], stderr=subprocess.PIPE, stdout=subprocess.PIPE,
                                text=True)
        _wait_for_jobs(out / "jobs", 2, proc)
        (worker, pid), = info["workers"].items()
        os.kill(pid, signal.SIGKILL)
        stdout, err = proc.communicate(timeout=120)
    finally:
        dask_cluster.stop(cluster)
    summary = json.loads(stdout)
    assert proc.returncode == 0 and summary["ok"] + summary["skipped"] == 10, err
    warned = [ln for ln in _ccl_lines(err) if "lost" in ln]
    assert len(warned) == 1 and worker in warned[0] and "retried on another worker" in warned[0], err
    now = job_metrics(out)
    assert all(values(now[k]) == values(clean_local[k]) for k in now)


def test_a_job_that_keeps_losing_its_worker_is_failed_not_retried_forever(monkeypatch):
    """The supervisor's bound, on a stand-in cluster: a job whose worker is lost twice is
    cancelled and failed naming the worker; the other jobs go on."""
    from ccl_cli.app import dask_jobs

    class Fut:
        def __init__(self, key):
            self.key, self.status, self.cancelled = key, "pending", False

        def done(self):
            return self.status != "pending"

        def result(self, timeout=None):
            return "done"

        def cancel(self, force=False):
            self.cancelled = True

        def release(self):
            pass

    class Client:
        status = "running"

        def __init__(self):
            self.futures, self.looks = {}, 0
            self.scheduler = type("S", (), {"address": "tcp://sched:1"})()

        def submit(self, fn, *args, key, pure):
            self.futures[key] = Fut(key)
            return self.futures[key]

        def scheduler_info(self, n_workers=-1):
            self.looks += 1
            # look 1: w1 holds job a; 2: w1 lost, w2 holds a; 3: w2 lost, w3 alive; then b finishes
            alive = {1: ["tcp://w1"], 2: ["tcp://w2"], 3: ["tcp://w3"]}.get(self.looks, ["tcp://w3"])
            if self.looks >= 4:
                self.futures["ccl-job-b"].status = "finished"
            return {"workers": dict.fromkeys(alive)}

        def processing(self):
            return {1: {"tcp://w1": ["ccl-job-a"]}, 2: {"tcp://w2": ["ccl-job-a"]}}.get(self.looks, {})

        def cancel(self, futures, force=False):
            pass

    import distributed

    monkeypatch.setattr(distributed, "wait", lambda fs, timeout, return_when: None)
    client = Client()
    done, failed = [], []
    dask_jobs.run_jobs(client, {"a": (print, ()), "b": (print, ())}, lambda j, r: done.append(j),
                       lambda j, why: failed.append((j, why)), worker_wait=60)
    assert done == ["b"] and client.futures["ccl-job-a"].cancelled
    assert failed == [("a", "worker tcp://w2 lost while running job a (2 workers lost with it; not retried)")]


def test_batch_as_an_unprivileged_user_never_writes_into_a_users_folder(recordings):
    """As the user nobody, into a folder another user made world-writable: refused, every
    file as it was; into a new folder: the batch runs."""
    from tests_paths import as_nobody, shared_folder

    prefix = as_nobody()
    root = shared_folder()
    try:
        for name in ("rec_00.h5", "pipeline.yaml"):
            shutil.copy(recordings / name, root / name)
            (root / name).chmod(0o644)
        user = root / "user"
        user.mkdir()
        user.chmod(0o777)
        (user / "summary.md").write_text("mine\n")
        args = [*prefix, CCL, "batch", "--files", str(root / "rec_00.h5"), "-c", str(root / "pipeline.yaml"),
                "-j", "1", "-q"]
        proc = subprocess.run([*args, "-o", str(user)], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 2 and "holds files ccl did not write" in proc.stderr, proc.stderr
        assert [p.name for p in user.iterdir()] == ["summary.md"]
        assert (user / "summary.md").read_text() == "mine\n"
        proc = subprocess.run([*args, "-o", str(root / "new")], capture_output=True, text=True, timeout=300)
        assert proc.returncode == 0, proc.stderr
    finally:
        shutil.rmtree(root, ignore_errors=True)
