"""What a researcher touches (issue 21): outputs that never refuse by default, --json errors,
-h, ccl inspect MODEL.h5, figures of ccl evaluate, vector figures, time plots with gaps."""

from __future__ import annotations

import json
import os

import numpy as np
from tests_paths import CCL

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import write_demonstrations


def test_two_runs_without_out_both_succeed_in_new_folders(capsys, tmp_path, monkeypatch):
    data = write_demonstrations(tmp_path / "arm.h5", sim.arm7(rows=(0,), n_demos=12, seed=1))
    monkeypatch.chdir(tmp_path)
    assert main(["learn-a", str(data), "-q"]) == 0
    assert main(["learn-a", str(data), "-q"]) == 0
    assert sorted(p.name for p in (tmp_path / "runs").iterdir()) == ["learn-a-arm", "learn-a-arm-2"]
    assert (tmp_path / "runs" / "learn-a-arm-2" / "model.h5").exists()


def test_json_errors_are_one_object_and_help_has_a_short_flag(capsys, tmp_path):
    code = main(["learn-a", str(tmp_path / "missing.h5"), "--json"])
    out = capsys.readouterr().out
    assert code == 2 and out.count("\n") == 1
    error = json.loads(out)
    assert error["status"] == "error" and error["exit_code"] == 2
    assert "missing.h5" in error["error"]["message"]
    import subprocess

    for args in (["-h"], ["learn-a", "-h"]):
        proc = subprocess.run([CCL, *args], capture_output=True, text=True)
        assert proc.returncode == 0 and "Usage: ccl" in proc.stdout


def test_inspect_a_model_names_its_method_and_constraints(capsys, tmp_path):
    data = write_demonstrations(tmp_path / "arm.h5", sim.arm7(rows=(0, 1), n_demos=12, seed=2))
    assert main(["learn-a", str(data), "-o", str(tmp_path / "o"), "-q"]) == 0
    capsys.readouterr()
    assert main(["inspect", str(tmp_path / "o" / "model.h5")]) == 0
    text = capsys.readouterr().out
    assert "method nhat" in text and "constraints: 2" in text and str(data) in text
    assert main(["inspect", str(tmp_path / "o" / "model.h5"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["n_constraints"] == 2 and info["training"]["metrics"]["test"]["NPPE"] < 1e-3


def test_evaluate_writes_the_figures_of_a_run_and_vector_output(capsys, tmp_path):
    data = write_demonstrations(tmp_path / "arm.h5", sim.arm7(rows=(0,), n_demos=12, seed=3))
    assert main(["learn-a", str(data), "-o", str(tmp_path / "o"), "-q"]) == 0
    model = tmp_path / "o" / "model.h5"
    assert main(["evaluate", str(model), str(data), "-o", str(tmp_path / "e"), "-q"]) == 0
    plots = sorted(p.name for p in (tmp_path / "e" / "plots").iterdir())
    assert "learn-a-time.png" in plots and "learn-a-constraint.png" in plots
    report = (tmp_path / "e" / "report.md").read_text()
    assert all(f"plots/{p}" in report for p in plots)
    cfg = tmp_path / "svg.yaml"
    cfg.write_text(f"data: {{files: [{data}]}}\noutput: {{format: svg}}\nstages: [learn-a]\n")
    assert main(["run", str(cfg), "-o", str(tmp_path / "s"), "-q"]) == 0
    svgs = list((tmp_path / "s" / "plots").glob("*.svg"))
    assert svgs and all(p.read_text().lstrip().startswith("<?xml") for p in svgs)


def test_time_plots_leave_gaps_as_gaps():
    from ccl_cli.render.figures import with_gaps

    t = np.r_[np.arange(10) * 0.1, 12.0 + np.arange(5) * 0.1]  # a 12-s gap (a training block)
    times, cut = with_gaps(t)
    assert np.isnan(times).sum() == 1 and np.isnan(times[10])
    assert np.isnan(cut(np.arange(15.0))[10]) and len(cut(np.arange(15.0))) == 16


def test_quiet_prints_nothing_on_success(tmp_path):
    import subprocess

    data = write_demonstrations(tmp_path / "arm.h5", sim.arm7(rows=(0,), n_demos=12, seed=4))
    proc = subprocess.run([CCL, "learn-a", str(data), "-o", str(tmp_path / "o"), "-q"], capture_output=True,
                          text=True, env={**os.environ, "COLUMNS": "200"})
    assert proc.returncode == 0 and proc.stdout == "" and proc.stderr == ""
