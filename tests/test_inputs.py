"""One way to pass recordings: every command that reads them takes several paths, globs and
folders alike (``ccl run CFG --data A B C``, ``ccl inspect A B``), a recording given twice is
refused by each, and ``--help`` says what a value is in words."""

import json
import re
from pathlib import Path

import numpy as np
import pytest

from ccl_cli.cli import app, main


def _drawers(folder: Path, n: int = 6, seed: int = 0) -> list[Path]:
    """``n`` headerless x y z text files (numpy.savetxt) of a hand pulling a drawer along one
    line: two constraints, each file one demonstration."""
    rng = np.random.default_rng(seed)
    folder.mkdir(parents=True, exist_ok=True)
    paths = []
    direction = np.array([0.8, 0.6, 0.0])
    for k in range(n):
        s = np.linspace(0, 0.3 + 0.02 * k, 120) ** 1.2
        X = np.array([0.1 * k, 0.2, 0.5]) + s[:, None] * direction + rng.normal(0, 2e-4, (120, 3))
        paths.append(folder / f"{k:03d}.log")
        np.savetxt(paths[-1], X)
    return paths


def _config(tmp_path: Path, files: str = "nothing/*.log") -> Path:
    cfg = tmp_path / "pipeline.yaml"
    cfg.write_text(f"data:\n  files: [{files}]\n  state: {{columns: [0, 1, 2], units: m}}\n"
                   "  action: {derive: state}\n  time: {rate: 10}\n  test: {fraction: 0.25, seed: 0}\n"
                   "output: {plots: false}\nstages: [learn-a]\n")
    return cfg


def _inputs(out: Path) -> list[str]:
    return [Path(f).name for f in json.loads((out / "run.json").read_text())["inputs"]]


def test_run_takes_several_recordings_after_data_as_a_shell_expands_a_glob(tmp_path, capsys):
    paths = _drawers(tmp_path / "logs")
    cfg = _config(tmp_path)
    out = tmp_path / "run"
    # as `ccl run CFG --data logs/*.log -o DIR` reaches ccl: the values run to the next option
    assert main(["run", str(cfg), "--data", *map(str, paths[:5]), "-o", str(out), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert _inputs(out) == ["000.log", "001.log", "002.log", "003.log", "004.log"]
    assert summary["stages"]["learn-a"]["n_constraints"] == 2  # a line: two constraints
    # the old form, one --data per file, still works
    out2 = tmp_path / "run2"
    assert main(["run", str(cfg), "--data", str(paths[0]), "--data", str(paths[1]), "-o", str(out2),
                 "-q"]) == 0
    assert _inputs(out2) == ["000.log", "001.log"]


def test_a_folder_stands_for_the_recordings_in_it(tmp_path, capsys):
    _drawers(tmp_path / "logs")
    (tmp_path / "logs" / "README.md").write_text("# drawer logs\n")
    (tmp_path / "logs" / ".hidden.log").write_text("1 2 3\n")
    (tmp_path / "logs" / "sub").mkdir()
    cfg = _config(tmp_path)
    out = tmp_path / "run"
    assert main(["learn-a", str(tmp_path / "logs"), "-c", str(cfg), "-o", str(out)]) == 0
    assert _inputs(out) == [f"{k:03d}.log" for k in range(6)]
    err = capsys.readouterr().err
    assert "6 recording(s); left out README.md, sub/ (not recordings)" in err
    # a folder named in the config's data.files too, relative to the config
    out2 = tmp_path / "run2"
    assert main(["run", str(_config(tmp_path, "logs")), "-o", str(out2), "-q"]) == 0
    assert len(_inputs(out2)) == 6
    # a folder without a recording is one line, exit 2
    (tmp_path / "notes").mkdir()
    (tmp_path / "notes" / "a.md").write_text("x")
    assert main(["learn-a", str(tmp_path / "notes"), "-c", str(cfg), "-o", str(tmp_path / "r3")]) == 2
    assert "a folder with no recording in it" in capsys.readouterr().err


@pytest.mark.parametrize("command", ["learn-a", "run", "convert", "evaluate", "predict", "inspect"])
def test_every_command_refuses_a_recording_given_twice(tmp_path, capsys, command):
    paths = _drawers(tmp_path / "logs", n=3)
    cfg = _config(tmp_path)
    same = [str(paths[0]), str(tmp_path / "logs" / ".." / "logs" / "000.log")]  # one file, two names
    model = tmp_path / "model.h5"
    if command in ("evaluate", "predict"):
        assert main(["learn-a", *map(str, paths), "-c", str(cfg), "-o", str(tmp_path / "m"), "-q"]) == 0
        model = tmp_path / "m" / "model.h5"
    args = {"learn-a": ["learn-a", *same, "-c", str(cfg), "-o", str(tmp_path / "o")],
            "run": ["run", str(cfg), "--data", *same, "-o", str(tmp_path / "o")],
            "convert": ["convert", *same, "-c", str(cfg), "-o", str(tmp_path / "o.h5")],
            "evaluate": ["evaluate", str(model), *same, "-c", str(cfg)],
            "predict": ["predict", str(model), *same, "-c", str(cfg), "-o", str(tmp_path / "p.csv")],
            "inspect": ["inspect", *same]}[command]
    capsys.readouterr()
    assert main(args) == 2
    err = capsys.readouterr().err.strip()
    assert err.count("\n") == 0 and "are the same file" in err
    assert not (tmp_path / "o").exists() and not (tmp_path / "o.h5").exists()
    assert not (tmp_path / "p.csv").exists()


def test_inspect_describes_each_of_several_files(tmp_path, capsys):
    from writers import joint_recording, write_ros1_bag

    paths = _drawers(tmp_path / "logs", n=2)
    bag = write_ros1_bag(tmp_path / "arm.bag", joint_recording(n=80))
    assert main(["inspect", str(paths[0]), str(bag), str(tmp_path / "logs" / "*.log")]) == 2  # 000 twice
    assert "000.log is given twice" in capsys.readouterr().err
    assert main(["inspect", str(bag), str(tmp_path / "logs")]) == 0
    text = capsys.readouterr().out
    blocks = text.strip().split("\n\n")
    assert [b.splitlines()[0] for b in blocks] == [f"path:     {bag}", f"path:     {paths[0]}",
                                                   f"path:     {paths[1]}"]
    assert "80 msgs" in blocks[0] and "rows:     120 (no time column)" in blocks[1]
    assert main(["inspect", str(bag), str(paths[1]), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert [f["format"] for f in info["files"]] == ["bag", "csv"]
    assert info["files"][1]["rows"] == 120 and info["files"][1]["columns"] == ["0", "1", "2"]
    # one file: the object itself, as before
    assert main(["inspect", str(bag), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["format"] == "bag"


def test_a_headerless_numeric_text_is_described_without_a_config(tmp_path, capsys):
    t = np.arange(150) * 0.02
    X = np.c_[np.sin(t), np.cos(t), 0.3 + 0 * t]
    np.savetxt(tmp_path / "spaces.txt", X)  # no time: a rate is needed
    np.savetxt(tmp_path / "timed.csv", np.c_[t, X], delimiter=",")  # column 0 increases: a time?
    np.savetxt(tmp_path / "wide.txt", X.T)  # the original library's layout: one sample per column
    assert main(["inspect", str(tmp_path / "spaces.txt"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert info["columns"] == ["0", "1", "2"] and info["rows"] == 150 and info["time_column"] is None
    assert info["header"] is False
    assert info["needs"][0].startswith("data.time: {rate: HZ}") and "column: 0" not in info["needs"][0]
    assert "data.state: {columns: [0, 1, 2]}" in info["needs"][1]
    assert main(["inspect", str(tmp_path / "timed.csv"), "--json"]) == 0
    info = json.loads(capsys.readouterr().out)
    assert "data.time: {column: 0} (column 0 increases throughout" in info["needs"][0]
    assert "data.state: {columns: [1, 2, 3]}" in info["needs"][1]
    assert main(["inspect", str(tmp_path / "wide.txt")]) == 0
    text = capsys.readouterr().out
    assert "rows:     3 (no time column)" in text
    assert "data.state: {samples: columns} if each of the 150 columns is a sample" in text
    # and with what it says, the file reads
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {state: {columns: [1, 2, 3]}, action: {derive: state}, time: {column: 0}}\n")
    assert main(["inspect", str(tmp_path / "timed.csv"), "-c", str(cfg), "--json"]) == 0
    assert json.loads(capsys.readouterr().out)["as_configured"]["samples"] == 150


def _help_texts() -> dict[str, str]:
    from typer.testing import CliRunner

    runner = CliRunner()
    names = [info.name for info in app.registered_commands]
    return {name: runner.invoke(app, [name, "--help"]).output for name in names} | \
        {"ccl": runner.invoke(app, ["--help"]).output}


def test_help_says_values_in_words_not_python_types():
    texts = _help_texts()
    assert len(texts) == 12
    for name, text in texts.items():
        assert text.startswith("Usage: "), name
        assert not re.search(r"<(list|path|int|float|str|bool)\b|list\[|\{[a-z_]+\}", text), (name, text)
    assert "Usage: ccl run [OPTIONS] PIPELINE" in texts["run"]
    assert "--data PATH..." in texts["run"] and "--seed INTEGER" in texts["run"]
    assert "Usage: ccl learn-a [OPTIONS] [DATA]..." in texts["learn-a"]
    assert "--method auto|nhat|alpha|lambda|linear|per_window|per_segment|manifold" in texts["learn-a"]
    assert "Usage: ccl evaluate [OPTIONS] MODEL [DATA]..." in texts["evaluate"]
    assert "--format-version INTEGER" in texts["convert"] and "from 1 to 2" in texts["convert"]
    assert "[default: config, else 0]" in re.sub(r"\s+", " ", texts["run"])


def test_message_types_are_named_alike_in_every_container(tmp_path, capsys):
    """The same JointState messages in a ROS 1 bag, a ROS 1 MCAP, a ROS 2 MCAP, a ROS 2 bag and a
    JSON MCAP: one type name (package/msg/Type) and the message encoding as MCAP names it."""
    from writers import (
        joint_recording,
        write_mcap_json,
        write_mcap_ros1,
        write_mcap_ros2,
        write_ros1_bag,
        write_ros2_bag,
    )

    rec = joint_recording(n=40)
    files = [write_ros1_bag(tmp_path / "a.bag", rec), write_mcap_ros1(tmp_path / "a1.mcap", rec),
             write_mcap_ros2(tmp_path / "a2.mcap", rec), write_ros2_bag(tmp_path / "bag2", rec),
             write_mcap_json(tmp_path / "aj.mcap", rec)]
    assert main(["inspect", *map(str, files), "--json"]) == 0
    infos = json.loads(capsys.readouterr().out)["files"]
    assert [i["topics"]["/joint_states"]["type"] for i in infos] == ["sensor_msgs/msg/JointState"] * 5
    assert [i["encoding"] for i in infos] == ["ros1", "ros1", "cdr", "cdr", "json"]


def _documented_flags() -> list[tuple[str, str, str, str]]:
    """(file, command, flag, line) of every ``ccl COMMAND ... --flag`` in the README's and docs'
    code (inline spans and blocks)."""
    root = Path(__file__).resolve().parent.parent
    found = []
    for doc in [root / "README.md", *sorted((root / "docs").rglob("*.md"))]:
        text = doc.read_text()
        spans = re.findall(r"```[a-z]*\n(.*?)```", text, re.S)
        spans += re.findall(r"`([^`\n]+)`", re.sub(r"```[a-z]*\n.*?```", "", text, flags=re.S))
        for line in (ln for span in spans for ln in span.splitlines()):
            for m in re.finditer(r"\bccl ([a-z][a-z-]*)([^|;&#]*)", line):
                found += [(doc.name, m.group(1), flag, line.strip())
                          for flag in re.findall(r"(?<![\w-])(--?[a-zA-Z][\w-]*)", m.group(2))]
    return found


def test_every_flag_the_docs_show_exists_on_the_command_they_show_it_with():
    import typer.main

    group = typer.main.get_command(app)
    options = {name: {o for p in c.params for o in (*p.opts, *p.secondary_opts)}
               for name, c in group.commands.items()}
    common = {o for p in group.params for o in p.opts}
    documented = [d for d in _documented_flags() if d[1] in options]
    assert len(documented) > 40 and ("README.md", "run", "--n-centres") in [d[:3] for d in documented]
    missing = [d for d in documented if d[2] not in options[d[1]] | common]
    assert missing == []


def test_run_takes_the_basis_flags_of_the_stages_that_have_a_basis(tmp_path, capsys):
    from ccl_cli.models import load_model

    configs = Path(__file__).resolve().parent.parent / "configs"
    out = tmp_path / "run"
    assert main(["run", str(configs / "toy2d_learn_pi.yaml"), "--n-centres", "9", "-o", str(out), "-q"]) == 0
    policy, _ = load_model(out / "models" / "learn-pi.h5")
    assert policy.basis_.centres_.shape == (9, 2)  # the config says 100 on a grid
    assert main(["run", str(_config(tmp_path)), "--n-centres", "9", "-o", str(tmp_path / "r2")]) == 2
    assert "--n-centres: no stage of" in capsys.readouterr().err and not (tmp_path / "r2").exists()


def test_shell_completion_is_enabled():
    import os
    import subprocess

    from tests_paths import CCL

    env = {**os.environ, "_CCL_COMPLETE": "complete_bash", "COMP_WORDS": "ccl learn-a --method ",
           "COMP_CWORD": "3"}
    done = subprocess.run([CCL], env=env, capture_output=True, text=True, timeout=120)
    assert done.returncode == 0
    assert done.stdout.split() == ["auto", "nhat", "alpha", "lambda", "linear", "per_window", "per_segment",
                                   "manifold"]
    env |= {"COMP_WORDS": "ccl le", "COMP_CWORD": "1"}
    done = subprocess.run([CCL], env=env, capture_output=True, text=True, timeout=120)
    assert done.stdout.split() == ["learn-a", "learn-v", "learn-pi"]
    script = subprocess.run([CCL, "--show-completion", "bash"], capture_output=True, text=True, timeout=120)
    assert "_CCL_COMPLETE=complete_bash" in script.stdout
