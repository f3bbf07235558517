"""What a user sees: the progress of a run (stages named with their method, a search's
candidates) and what inspect says of a recording (dates, storage, compression, encoding)."""

from pathlib import Path

import pytest

from ccl_cli import config
from ccl_cli.app.run import execute

CONFIGS = Path(__file__).resolve().parent.parent / "configs"


class Recorder:
    def __init__(self) -> None:
        self.events: list[str] = []

    def start(self, label: str) -> None:
        self.events.append(f"start {label}")

    def advance(self) -> None:
        self.events.append("done")


def test_each_stage_is_named_with_its_method_before_it_runs():
    cfg = config.load(CONFIGS / "toy2d_learn_v_then_a.yaml")
    shown = Recorder()
    result = execute("run", cfg, None, progress=shown, views=False)
    assert shown.events == ["start learn-v (ncl)", "done", "start learn-a (nhat)", "done",
                            "start evaluate (every model under the ccl convention)", "done"]
    assert [r.name for r in result.pipeline.results] == ["learn-v", "learn-a", "evaluate"]


def test_inspect_dates_are_utc_and_a_boot_clock_is_not_a_date():
    from ccl_cli.render.text import utc

    assert utc(1_700_000_000_002_000_000) == "2023-11-14 22:13:20.002 UTC"  # date -u -d @1700000000
    assert utc(12_500_000_000).startswith("12.500 s (a clock that is not a date")


def test_a_search_reports_its_candidates_through_the_progress_hook():
    """Inside a stage the bar shows the search's candidates: the library reports them through
    ccl_cli.progress (nothing is shown unless a front end installed a hook)."""
    from contextlib import contextmanager

    import numpy as np

    from ccl_cli import progress
    from ccl_cli.learn.nullspace import NullSpaceComponent

    seen: list[tuple[str, float, float]] = []

    @contextmanager
    def hook(label, total):
        done = [0.0]

        def advance(units):
            done[0] += units
            seen.append((label, done[0], total))

        yield advance

    rng = np.random.default_rng(0)
    X = rng.uniform(-1, 1, (300, 2))
    U = np.c_[X[:, 1], -X[:, 0]] + 0.01 * rng.normal(size=(300, 2))
    previous = progress.install(hook)
    try:
        model = NullSpaceComponent(seed=0).fit(X, U, groups=np.repeat(np.arange(6), 50))
    finally:
        progress.install(previous)
    ran = len(model.tuning_["scores"])
    labels = {label for label, _, _ in seen}
    assert labels == {"tuning, candidates"}
    total = seen[0][2]
    assert ran - 1 <= max(done for _, done, _ in seen) <= total  # advanced as each later candidate began
    assert ran <= total


@pytest.mark.parametrize("container", ["ros1", "ros1-bz2", "ros2", "mcap"])
def test_inspect_names_storage_compression_and_encoding(tmp_path, capsys, container):
    import json

    from writers import joint_recording, write_mcap_ros2, write_ros1_bag, write_ros2_bag

    from ccl_cli.cli import main

    rec = joint_recording(n=100)
    path = {"ros1": lambda: write_ros1_bag(tmp_path / "a.bag", rec),
            "ros1-bz2": lambda: write_ros1_bag(tmp_path / "a.bag", rec, compress=True),
            "ros2": lambda: write_ros2_bag(tmp_path / "b", rec),
            "mcap": lambda: write_mcap_ros2(tmp_path / "r.mcap", rec)}[container]()
    assert main(["inspect", str(path), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    expected = {"ros1": ("ROS 1 bag", "none", "ros1"), "ros1-bz2": ("ROS 1 bag", "bz2", "ros1"),
                "ros2": ("ROS 2 bag (sqlite3", "none", "cdr"), "mcap": ("MCAP", "zstd", "cdr")}[container]
    assert info["storage"].startswith(expected[0])
    assert info["compression"] == expected[1] and info["encoding"] == expected[2]


def _run_ccl(args: list[str], stderr_tty: bool) -> str:
    """stderr of ``ccl ARGS`` written to a pipe, or to a pseudo-terminal."""
    import os
    import pty
    import subprocess

    from tests_paths import CCL as exe
    if not stderr_tty:
        return subprocess.run([exe, *args], capture_output=True, text=True, check=True).stderr
    master, slave = pty.openpty()
    proc = subprocess.Popen([exe, *args], stdout=subprocess.DEVNULL, stderr=slave)
    os.close(slave)
    chunks = []
    while True:
        try:
            data = os.read(master, 65536)
        except OSError:  # the child closed the terminal
            break
        if not data:
            break
        chunks.append(data)
    proc.wait()
    os.close(master)
    assert proc.returncode == 0
    return b"".join(chunks).decode(errors="replace")


def test_a_terminal_gets_the_progress_bar_and_a_pipe_gets_none(tmp_path):
    args = ["run", str(CONFIGS / "toy2d_learn_v_then_a.yaml"), "-o", str(tmp_path / "r"), "--force"]
    piped = _run_ccl(args, stderr_tty=False)
    assert "━" not in piped and "\r" not in piped and "\x1b[" not in piped
    assert "ccl: stage learn-v (ncl)" in piped  # one plain line per stage instead
    shown = _run_ccl([*args[:3], str(tmp_path / "t"), "--force"], stderr_tty=True)
    assert "━" in shown and "learn-v (ncl)" in shown
    assert "ccl: stage learn-v" not in shown  # the bar names the stage; no log line under it
