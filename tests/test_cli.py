"""End-to-end: the installed ``ccl`` entry point (subprocess) and ``ccl_cli.cli.main``."""

import json
import os
import shutil
import signal
import subprocess
import sys
import time
from pathlib import Path

import h5py
import numpy as np
import pytest
from tests_paths import wait_for_ccl_code

from ccl_cli.cli import main

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
SAMPLES = ROOT / "sample_data"
CCL = shutil.which("ccl") or str(Path(sys.executable).parent / "ccl")


def ccl(*args, cwd=None, check=True):
    proc = subprocess.run([CCL, *map(str, args)], capture_output=True, text=True, cwd=cwd)
    if check and proc.returncode != 0:
        raise AssertionError(f"ccl {' '.join(map(str, args))} → {proc.returncode}\n{proc.stderr}")
    return proc


def run_main(capsys, *args):
    code = main([str(a) for a in args])
    out = capsys.readouterr()
    return code, out.out, out.err


def metrics_of(outdir: Path) -> dict:
    return json.loads((outdir / "metrics.json").read_text())


# -- every shipped pipeline, with the accuracy bars of the learning core ----------------------
def test_pipeline_toy2d_learn_v(tmp_path):
    proc = ccl("run", CONFIGS / "toy2d_learn_v.yaml", "-o", tmp_path / "v", "--json")
    summary = json.loads(proc.stdout)
    assert summary["stages"]["learn-v"]["test"]["NUPE_w"] < 1e-3
    out = tmp_path / "v"
    assert {p.name for p in out.iterdir()} >= {"model.h5", "metrics.json", "report.md", "run.json",
                                               "config.yaml", "plots"}
    assert (out / "plots" / "learn-v-field.png").stat().st_size > 1000
    assert "![learn-v" in (out / "report.md").read_text()
    run = json.loads((out / "run.json").read_text())
    assert run["inputs"] and all(len(h) == 64 for h in run["inputs"].values())
    assert run["versions"]["numpy"] == np.__version__


def test_pipeline_learn_v_then_a_on_learnt_w(capsys, tmp_path):
    code, out, err = run_main(capsys, "run", CONFIGS / "toy2d_learn_v_then_a.yaml", "-o", tmp_path / "va",
                              "--json", "-q")
    assert code == 0, err
    stages = json.loads(out)["stages"]
    assert stages["learn-a"]["n_constraints"] == 1
    assert stages["learn-a"]["test"]["NPPE"] < 1e-4
    assert (tmp_path / "va" / "models" / "learn-v.h5").exists()
    assert (tmp_path / "va" / "models" / "learn-a.h5").exists()


def test_pipeline_arm7_two_link_and_real_formats(capsys, tmp_path):
    bars = {"arm7": ("NPPE", 1e-4), "two_link": ("NPPE", 5e-6), "trakstar_csv": ("NPOE", 1e-3),
            "kuka_bag": ("NPOE", 1e-4), "toy2d_learn_a": ("NPPE", 1e-3)}
    for name, (metric, bar) in bars.items():
        code, out, err = run_main(capsys, "run", CONFIGS / f"{name}.yaml", "-o", tmp_path / name, "--json",
                                  "-q")
        assert code == 0, (name, err)
        stage = json.loads(out)["stages"]["learn-a"]
        assert stage["test"][metric] < bar, (name, stage)
    assert metrics_of(tmp_path / "arm7")["learn-a"]["n_constraints"] == 2
    tuning = metrics_of(tmp_path / "two_link")["learn-a"]["tuning"]  # lambda's default grid: 16, 25 centres
    assert [r["params"]["basis"]["n_centres"] for r in tuning["scores"]] == [16, 25]
    assert tuning["chosen"]["basis"]["n_centres"] == 25
    assert "learn-a: hyperparameters by cross-validation" in (tmp_path / "two_link" / "report.md").read_text()


def test_pipeline_learn_pi_coupled_to_learnt_constraints(capsys, tmp_path):
    code, out, err = run_main(capsys, "run", CONFIGS / "toy2d_learn_pi.yaml", "-o", tmp_path / "pi", "--json",
                              "-q")
    assert code == 0, err
    stage = json.loads(out)["stages"]["learn-pi"]
    pi = stage["test"]
    assert pi["NUPE"] < 0.05
    assert stage["baseline"]["method"] == "dpl"
    assert stage["baseline"]["test"]["NUPE"] > 0.3  # the biased baseline, reported next to it


# -- single commands, saved models ----------------------------------------------------------
def test_simulate_learn_evaluate_predict_round_trip(tmp_path):
    data = tmp_path / "arm.h5"
    ccl("simulate", "arm7", "-o", data, "--seed", "3", "--test-fraction", "0.3")
    info = json.loads(ccl("inspect", data, "--json").stdout)
    assert info["format"] == "hdf5" and info["masks"] == {"train": 35, "test": 15}
    ccl("learn-a", data, "-o", tmp_path / "a", "--selection", "eigengap", "-q")
    model = tmp_path / "a" / "model.h5"
    ev = json.loads(ccl("evaluate", model, data, "--json").stdout)
    assert ev["kind"] == "constraint" and ev["metrics"]["NPPE"] < 1e-4
    ccl("predict", model, data, "-o", tmp_path / "pred.h5")
    # bit-identical predictions: a new process vs this one
    from ccl_cli.io import read_demonstrations
    from ccl_cli.models import load_model

    est, _ = load_model(model)
    d, _ = read_demonstrations(data)
    with h5py.File(tmp_path / "pred.h5") as f:
        assert np.array_equal(f["N"][()], est.projection(d.X, groups=d.demo))
    ccl("predict", model, data, "-o", tmp_path / "pred.csv")
    header = (tmp_path / "pred.csv").read_text().splitlines()[0].split(",")
    assert header[:2] == [f"x.{n}" for n in d.state_names[:2]] and "N[6][6]" in header
    assert header[header.index("t [s]") - 1] == f"u.{d.action_names[-1]}"
    with h5py.File(tmp_path / "pred.h5") as f:  # names and units beside each dataset
        assert list(f["w"].attrs["names"]) == [f"w.{n}" for n in d.action_names]
        assert len(f["N"].attrs["names"]) == 49


@pytest.mark.parametrize("kind", ["alpha", "lambda", "linear", "ncl", "policy", "per_demo"])
def test_every_model_kind_reloads_bit_identically(tmp_path, kind):
    from ccl_cli import simulate as sim
    from ccl_cli.learn.constraint import (
        KnownFeatureConstraint,
        LinearConstraint,
        PerDemonstration,
        StateDependentConstraint,
    )
    from ccl_cli.learn.nullspace import NullSpaceComponent
    from ccl_cli.learn.policy import PolicyLearner
    from ccl_cli.models import load_model, save_model

    if kind == "lambda":
        d = sim.two_link(n_demos=8, n_steps=20)
    else:
        d = sim.toy2d(n_demos=10, vary_constraint=True)
    model = {"alpha": lambda: StateDependentConstraint(n_restarts=1),
             "lambda": lambda: KnownFeatureConstraint(features="arm2", n_restarts=1),
             "linear": lambda: LinearConstraint(regressors="rbf", n_centres=4),
             "ncl": lambda: NullSpaceComponent(n_centres=9),
             "policy": lambda: PolicyLearner(method="pi-weighted", n_centres=9),
             "per_demo": lambda: PerDemonstration(LinearConstraint(regressors="identity"))}[kind]()
    model.fit(d.X, d.U, groups=d.demo) if kind == "per_demo" else model.fit(d.X, d.U)
    path = save_model(tmp_path / "m.h5", model)
    code = ("import sys, numpy as np; from ccl_cli.models import load_model; "
            "from ccl_cli.io import read_demonstrations; m, i = load_model(sys.argv[1]); "
            "d, _ = read_demonstrations(sys.argv[2]); "
            "out = m.predict(d.X) if i['kind'] != 'constraint' else m.projection(d.X, groups=d.demo); "
            "np.save(sys.argv[3], out)")
    from ccl_cli.io import write_demonstrations

    write_demonstrations(tmp_path / "d.h5", d)
    subprocess.run([sys.executable, "-c", code, path, tmp_path / "d.h5", tmp_path / "out.npy"], check=True)
    fresh = np.load(tmp_path / "out.npy")
    here = model.predict(d.X) if kind in ("ncl", "policy") else model.projection(d.X, groups=d.demo)
    assert np.array_equal(fresh, here)
    again, _ = load_model(path)
    assert type(again) is type(model)


def test_convert_then_learn_from_bag_and_inspect(tmp_path):
    out = tmp_path / "kuka.h5"
    ccl("convert", SAMPLES / "kuka_wipe.bag", "-c", CONFIGS / "kuka_bag.yaml", "-o", out)
    info = json.loads(ccl("inspect", out, "--json").stdout)
    assert info["demos"] == 4 and info["samples"] == 1200
    bag = json.loads(ccl("inspect", SAMPLES / "kuka_wipe.bag", "--json").stdout)
    assert bag["topics"]["/joint_states"]["count"] == 1200
    assert bag["topics"]["/joint_states"]["rate_hz"] == pytest.approx(100.0)  # over the active time
    assert bag["demos"] == 4  # the shipped config's split, found without --gap
    text = ccl("inspect", SAMPLES / "trakstar_plane.csv").stdout
    assert "x.1" in text and "rows:" in text


def test_flags_override_config(capsys, tmp_path):
    code, out, err = run_main(capsys, "learn-a", "-c", CONFIGS / "arm7.yaml", "--n-constraints", "3", "-o",
                              tmp_path / "o", "--json", "-q")
    assert code == 0, err
    assert json.loads(out)["stages"]["learn-a"]["n_constraints"] == 3
    resolved = (tmp_path / "o" / "config.yaml").read_text()
    assert "n_constraints: 3" in resolved


# -- bad input and bad config: exit 2, one line, no traceback ------------------------------
BAD_CONFIGS = {
    "unknown_key": ("data:\n  files: [x.h5]\nlearn-a:\n  n_centers: 3\n",
                    r":4: unknown key 'n_centers' in learn-a \(did you mean 'n_centres'\?\)"),
    "wrong_type": ("learn-a:\n  n_constraints: two\n", r":2: learn-a.n_constraints must be an integer"),
    "bad_choice": ("learn-a:\n  method: nhatt\n", r"learn-a.method must be one of .*did you mean 'nhat'"),
    "bad_stage": ("stages:\n  - learn-ax\n", r":2: unknown stage 'learn-ax' \(did you mean 'learn-a'"),
    "bad_yaml": ("data: [unclosed\n", r"invalid YAML"),
    "top_level": ("dat:\n  files: []\n", r":1: unknown key 'dat' at the top level \(did you mean 'data'"),
}


@pytest.mark.parametrize("case", sorted(BAD_CONFIGS))
def test_bad_configs(capsys, tmp_path, case):
    import re

    text, pattern = BAD_CONFIGS[case]
    cfg = tmp_path / "bad.yaml"
    cfg.write_text(text)
    code, out, err = run_main(capsys, "learn-a", SAMPLES / "arm7.h5", "-c", cfg, "-o", tmp_path / "o")
    assert code == 2
    assert err.count("\n") == 1 and "Traceback" not in err
    assert re.search(pattern, err), err
    assert not (tmp_path / "o").exists()


def test_bad_inputs_exit_2_with_one_line(tmp_path):
    (tmp_path / "junk.h5").write_bytes(b"\x89HDF\r\n\x1a\n" + b"\x00" * 100)
    (tmp_path / "notamodel.h5").write_bytes((SAMPLES / "arm7.h5").read_bytes())
    cases = [
        ("learn-a", tmp_path / "missing.bag"),
        ("learn-a", tmp_path / "junk.h5"),
        ("learn-a", SAMPLES / "kuka_wipe.bag"),  # no data.state for a bag
        ("learn-a", SAMPLES / "arm7.h5", "--method", "lambda"),  # lambda needs features
        ("evaluate", tmp_path / "notamodel.h5", SAMPLES / "arm7.h5"),
        ("evaluate", tmp_path / "missing.h5", SAMPLES / "arm7.h5"),
        ("simulate", "nope", "-o", tmp_path / "x.h5"),
        ("simulate", "arm7", "-o", tmp_path / "x.h5", "--policy", "attractor"),
        ("inspect", tmp_path / "missing.csv"),
        ("learn-a", "--bogus-flag"),
    ]
    for args in cases:
        proc = ccl(*args, check=False)
        assert proc.returncode == 2, (args, proc.stderr)
        assert "Traceback" not in proc.stderr, (args, proc.stderr)
        if args[-1] != "--bogus-flag":
            lines = proc.stderr.strip().splitlines()
            assert lines[-1].startswith("ccl: error: "), (args, proc.stderr)
            assert sum(line.startswith("ccl: error") for line in lines) == 1
            assert all(line.startswith("ccl: ") for line in lines)  # progress logs, then the error


def test_dimension_mismatch_and_existing_output(tmp_path):
    ccl("learn-a", SAMPLES / "arm7.h5", "-o", tmp_path / "a", "-q")
    proc = ccl("evaluate", tmp_path / "a" / "model.h5", SAMPLES / "two_link.h5", check=False)
    assert proc.returncode == 2 and "7-dimensional actions" in proc.stderr
    proc = ccl("learn-a", SAMPLES / "arm7.h5", "-o", tmp_path / "a", check=False)
    assert proc.returncode == 2 and "exists; use --force" in proc.stderr
    ccl("learn-a", SAMPLES / "arm7.h5", "-o", tmp_path / "a", "--force", "-q")


def test_corrupt_model_is_refused(tmp_path):
    ccl("learn-v", SAMPLES / "toy2d_ncl.h5", "-o", tmp_path / "v", "-q")
    model = tmp_path / "v" / "model.h5"
    with h5py.File(model, "a") as f:
        del f["arrays/W_"]
        f["arrays/W_"] = np.zeros((3, 3))
    proc = ccl("evaluate", model, SAMPLES / "toy2d_ncl.h5", check=False)
    assert proc.returncode == 2 and "wrong shape" in proc.stderr
    raw = model.read_bytes()
    model.write_bytes(raw[: len(raw) // 2])
    proc = ccl("evaluate", model, SAMPLES / "toy2d_ncl.h5", check=False)
    assert proc.returncode == 2 and proc.stderr.count("\n") == 1


# -- interruption leaves nothing half-written ------------------------------------------------
def test_interrupted_write_leaves_no_output(capsys, tmp_path, monkeypatch):
    import ccl_cli.render.outputs as report

    def boom(*a, **k):
        raise KeyboardInterrupt

    monkeypatch.setattr(report, "write_json", boom)
    code, _, err = run_main(capsys, "learn-a", SAMPLES / "arm7.h5", "-o", tmp_path / "o")
    assert code == 130 and "interrupted" in err
    assert list(tmp_path.iterdir()) == []


def test_sigint_during_a_run_leaves_complete_or_nothing(tmp_path):
    out = tmp_path / "o"
    env = dict(os.environ)
    proc = subprocess.Popen([CCL, "run", str(CONFIGS / "toy2d_learn_pi.yaml"), "-o", str(out), "-q"],
                            stderr=subprocess.PIPE, text=True, env=env)
    wait_for_ccl_code(proc)  # not during the interpreter's own start-up (a loaded machine: > 1 s)
    time.sleep(1.0)
    proc.send_signal(signal.SIGINT)
    _, err = proc.communicate(timeout=60)
    leftovers = [p.name for p in tmp_path.iterdir() if p.name != "o"]
    assert leftovers == []
    if out.exists():  # finished before the signal: then it is complete
        assert (out / "metrics.json").exists() and (out / "run.json").exists()
    else:
        assert proc.returncode == 130 and "Traceback" not in err


def test_evaluate_stage_applies_its_convention(capsys, tmp_path):
    cfg = tmp_path / "p.yaml"
    cfg.write_text(f"data: {{files: [{SAMPLES / 'toy2d_ncl.h5'}], test: {{fraction: 0.5}}}}\n"
                   "stages:\n  - learn-v\n  - evaluate: {convention: original}\n")
    code, _, err = run_main(capsys, "run", cfg, "-o", tmp_path / "o", "-q")
    assert code == 0, err
    m = metrics_of(tmp_path / "o")
    ours, original = m["learn-v"]["train"]["NPE"], m["evaluate"]["train"]["learn-v.NPE"]
    assert original["error"] == pytest.approx(ours["error"])
    n = 500  # training samples: NPE's original normaliser uses ddof = 0
    assert original["normaliser"] == pytest.approx(ours["normaliser"] * (n - 1) / n)


# -- inspect: rates over the active time, joint names, demonstrations ---------------------------
@pytest.mark.parametrize("writer", ["ros2", "mcap"])
def test_inspect_rate_over_active_time_joints_and_default_demos(capsys, tmp_path, writer):
    from writers import JOINTS, joint_recording, write_mcap_ros2, write_ros2_bag

    rec = joint_recording(n=1001, rate=500.0, gap_after=400, gap_s=1.5)  # 500 Hz, one 1.5 s pause
    path = write_ros2_bag(tmp_path / "b", rec) if writer == "ros2" else \
        write_mcap_ros2(tmp_path / "r.mcap", rec)
    code, out, err = run_main(capsys, "inspect", path, "--json")
    assert code == 0, err
    info = json.loads(out)
    topic = info["topics"]["/joint_states"]
    assert topic["count"] == 1001
    assert topic["rate_hz"] == pytest.approx(500.0, rel=1e-3)  # not 1000 / 3.5 s = 286 Hz
    assert topic["joint_names"] == JOINTS
    assert {"name", "position", "velocity"} <= set(topic["fields"])
    assert info["demos"] == 2  # found with the default gap, no --gap and no -c
    code, out, _ = run_main(capsys, "inspect", path, "--json", "--gap", "2.0")  # --gap without -c
    assert json.loads(out)["demos"] == 1
    code, out, _ = run_main(capsys, "inspect", path)
    assert "500.0 Hz" in out and "joints:" in out and "pauses:   2 stretches" in out


@pytest.mark.parametrize("split", [None, 0.5])
def test_inspect_with_a_config_says_what_learning_reads(capsys, tmp_path, split):
    """inspect -c and learn-a with the same config agree on the demonstrations: the pauses
    inspect finds are listed apart from the demonstrations the config cuts."""
    from writers import joint_recording, write_mcap_ros2

    rec = joint_recording(n=1001, rate=500.0, gap_after=400, gap_s=1.5)
    path = write_mcap_ros2(tmp_path / "r.mcap", rec)
    data = {"state": {"topic": "/joint_states", "field": "position"},
            "action": {"topic": "/joint_states", "field": "velocity"}}
    if split is not None:
        data["demos"] = {"split_on_gap": split}
    config = tmp_path / "c.yaml"
    config.write_text(json.dumps({"data": data, "learn-a": {"method": "nhat"}, "stages": ["learn-a"]}))
    code, out, err = run_main(capsys, "inspect", path, "-c", config, "--json")
    assert code == 0, err
    info = json.loads(out)
    assert info["demos"] == 2  # stretches between pauses
    read = info["as_configured"]
    code, out, err = run_main(capsys, "learn-a", path, "-c", config, "-o", tmp_path / "la", "--json", "-q")
    assert code == 0, err
    learnt = json.loads(out)
    expected = 1 if split is None else 2
    assert read["demos"] == expected and read["samples"] == 1001
    assert sum(read["samples_per_demo"]) == 1001 and len(read["samples_per_demo"]) == expected
    said = "a single continuous recording" if expected == 1 else f"only {expected} demonstrations"
    assert learnt["validation"]["reason"].startswith(said), learnt["validation"]
    code, out, _ = run_main(capsys, "inspect", path, "-c", config)
    assert f"learning reads: {expected} demonstration(s), 1001 samples" in out


# -- command-line conventions ------------------------------------------------------------------
def test_version_and_help_show_defaults_and_choices(capsys):
    from ccl_cli import __version__

    code, out, _ = run_main(capsys, "--version")
    assert code == 0 and out.strip() == f"ccl {__version__}"
    from typing import get_args

    from ccl_cli.learn.constraint import StateIndependentConstraint
    from ccl_cli.learn.params import SelectionRule

    proc = ccl("learn-a", "--help")
    text = " ".join(proc.stdout.split())
    assert "--method auto|nhat|alpha|lambda|linear|per_window|per_segment|manifold " in text
    assert "[default: config, else auto]" in text
    assert f"--selection {'|'.join(get_args(SelectionRule))} " in text
    assert f"[default: config, else {StateIndependentConstraint().selection}]" in text
    assert "--convention ccl|original " in text
    assert "[default: config, else pi]" in " ".join(ccl("learn-pi", "--help").stdout.split())


def test_flag_overrides_a_basis_mapping_at_any_depth(capsys, tmp_path):
    from ccl_cli import config as C
    from ccl_cli.learn.nullspace import NullSpaceComponent
    from ccl_cli.models import load_model

    cfg_path = tmp_path / "v.yaml"
    cfg_path.write_text(f"data: {{files: [{SAMPLES / 'toy2d_ncl.h5'}]}}\n"
                        "learn-v: {basis: {kind: rbf, n_centres: 4}, tune: false}\n")  # fixed settings
    code, _, err = run_main(capsys, "learn-v", "-c", cfg_path, "--n-centres", "25", "-o", tmp_path / "o",
                            "-q")
    assert code == 0, err
    assert load_model(tmp_path / "o" / "model.h5")[0].basis_.centres_.shape == (25, 2)
    # over a stages item's own options too, and --basis keeps the mapping's other keys
    staged = tmp_path / "s.yaml"
    staged.write_text(cfg_path.read_text() + "stages:\n  - learn-v: {basis: {kind: rbf, n_centres: 9, "
                      "centres: grid}}\n")
    [(_, opts)] = C.load(staged, {"learn-v": {"n_centres": 25, "basis": "rbf"}}).stages()
    params = opts.estimator_params(NullSpaceComponent)
    assert params["basis"] == {"kind": "rbf", "n_centres": 25, "centres": "grid"}
    assert params["n_centres"] == 25
    assert params["tune"] is False  # the basis given on the command line is used, not searched over


def test_flag_errors_are_one_line_and_name_the_flag(capsys, tmp_path):
    from ccl_cli import config as C
    from ccl_cli.errors import ConfigError

    for args, flag in ((("learn-a", "--selection", "often"), "'--selection'"),
                       (("learn-pi", "--n-centres", "many"), "'--n-centres'"),
                       (("lern-a",), "No such command"), (("run",), "Missing argument")):
        code, out, err = run_main(capsys, *args)
        assert code == 2 and out == "", args
        assert err.count("\n") == 1 and err.startswith("ccl: error: ") and flag in err, (args, err)
        assert "Usage:" not in err and "Value error" not in err

    with pytest.raises(ConfigError) as info:
        C.load(CONFIGS / "arm7.yaml", {"learn-a": {"selection": "often"}})
    assert info.value.message.startswith("--selection: learn-a.selection must be one of")
    assert "<flags>" not in info.value.message and "\n" not in info.value.message


def test_quiet_prints_nothing_on_success(capsys, tmp_path):
    data = tmp_path / "d.h5"
    for args in (("simulate", "toy2d", "-o", data, "--n-demos", "6"),
                 ("learn-a", data, "-o", tmp_path / "a"),
                 ("evaluate", tmp_path / "a" / "model.h5", data),
                 ("predict", tmp_path / "a" / "model.h5", data, "-o", tmp_path / "p.csv"),
                 ("convert", data, "-o", tmp_path / "c.h5"),
                 ("run", CONFIGS / "arm7.yaml", "-o", tmp_path / "r")):
        code, out, err = run_main(capsys, *args, "-q")
        assert code == 0, (args, err)
        assert out == "" and err == "", (args, out, err)


def test_a_config_given_as_the_recording_is_refused_by_convert_as_by_learning(capsys, tmp_path):
    """convert reads without the app layer: a YAML file among the recordings is the same one
    line as for the learning commands, and nothing is written."""
    for command in ("convert", "learn-a"):
        out = tmp_path / f"{command}.out"
        code, _, err = run_main(capsys, command, CONFIGS / "arm7.yaml", "-o", out)
        assert code == 2 and err.count("\n") == 1, err
        assert "arm7.yaml: a YAML file is a config, not a recording" in err
        assert not out.exists()


def test_batch_validates_the_whole_plan_before_any_job(capsys, tmp_path):
    code, _, err = run_main(capsys, "batch", "--files", str(SAMPLES / "*.h5"), "-o", tmp_path / "b")
    assert code == 2 and "--config" in err and err.count("\n") == 1
    assert not (tmp_path / "b").exists()
    bare = tmp_path / "bare.yaml"
    bare.write_text("learn-a: {method: nhat}\n")  # no stages: no job can run
    code, _, err = run_main(capsys, "batch", "--files", str(SAMPLES / "arm7.h5"), "-c", bare, "-o",
                            tmp_path / "b")
    assert code == 2 and "no stages" in err
    assert not (tmp_path / "b").exists()


def test_matplotlib_font_cache_message_never_reaches_the_user(tmp_path):
    env = {k: v for k, v in os.environ.items() if k != "MPLCONFIGDIR"}
    env |= {"XDG_CACHE_HOME": str(tmp_path / "c"), "HOME": str(tmp_path)}
    proc = subprocess.run([CCL, "run", CONFIGS / "arm7.yaml", "-o", tmp_path / "r"], capture_output=True,
                          text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    assert "fontManager" not in proc.stderr and "Matplotlib" not in proc.stderr
    assert (tmp_path / "c" / "ccl" / "matplotlib").is_dir()


def test_the_script_ends_with_its_exit_code_and_everything_it_printed(tmp_path):
    """entry() leaves through the exit handlers and flushed streams without tearing down
    the interpreter: a --json summary read through a pipe is whole, the output folder
    complete, an error still one line with its exit code."""
    import os

    env = {k: v for k, v in os.environ.items() if k != "PYTHONUNBUFFERED"}  # stdout block-buffered
    out = tmp_path / "r"
    proc = subprocess.run([CCL, "run", str(CONFIGS / "toy2d_learn_pi.yaml"), "-o", str(out), "--json"],
                          capture_output=True, text=True, env=env)
    assert proc.returncode == 0, proc.stderr
    summary = json.loads(proc.stdout)
    assert summary["outdir"] == str(out) and summary["stages"].keys() == {"learn-a", "learn-pi", "evaluate"}
    assert {"config.yaml", "metrics.json", "models", "plots", "report.md", "run.json"} <= \
        {p.name for p in out.iterdir()}
    assert len(list((out / "plots").glob("*.png"))) == 5
    assert json.loads((out / "run.json").read_text())["command"] == "run"
    bad = subprocess.run([CCL, "run", str(tmp_path / "missing.yaml"), "--json"], capture_output=True,
                         text=True, env=env)
    assert bad.returncode == 2
    assert bad.stderr.strip().splitlines() == [f"ccl: error: {tmp_path / 'missing.yaml'}: no such file"]
    assert json.loads(bad.stdout)["exit_code"] == 2


@pytest.mark.parametrize("args", [["run", "--help"], ["learn-a", "--help"], ["batch", "--help"],
                                  ["run", "--bogus"], ["evaluate"]])
def test_a_command_run_alone_says_what_the_whole_app_says(capsys, args):
    """main() builds only the invoked command (cli._app_for): its help and its usage errors
    are those of the app holding every command."""
    from ccl_cli.cli import _app_for, app

    assert len(_app_for(args).registered_commands) == 1
    code = main(args)
    alone = capsys.readouterr()
    try:
        whole = app(args=args, prog_name="ccl", standalone_mode=False)
    except Exception as exc:  # noqa: BLE001 - the usage error main() turned into one line
        whole = exc
    full = capsys.readouterr()
    if args[-1] == "--help":
        assert code == 0 and alone.out == full.out and "Usage: ccl " + args[0] in alone.out
    else:
        assert code == 2 and f"ccl {args[0]}" in alone.err
        assert str(getattr(whole, "message", whole)) in alone.err
