"""File names that are not UTF-8 (any bytes but / and NUL a Linux file system allows): read,
written and reported by every command, and matched by batch globs. Python holds such a name
as surrogate escapes (os.fsdecode); text outputs write it back as its own bytes."""

from __future__ import annotations

import json
import os
import shutil
from pathlib import Path

import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import write_demonstrations


def odd(folder: Path, raw: bytes) -> Path:
    """``folder``/``raw`` as a path Python can pass to the file system."""
    return folder / os.fsdecode(raw)


@pytest.fixture(scope="module")
def names(tmp_path_factory):
    root = tmp_path_factory.mktemp("names")
    data = odd(root, b"rec\xff\xfe.h5")
    try:
        write_demonstrations(data, sim.toy2d(n_demos=6, n_steps=40, seed=0))
    except (OSError, UnicodeEncodeError):
        pytest.skip("this file system refuses names that are not UTF-8")
    csv = odd(root, b"track\xe9.csv")
    csv.write_text("time,x,y\n" + "".join(f"{i * 0.02:.2f},{0.1 * i},{(0.1 * i) ** 2}\n"
                                          for i in range(120)))
    (root / "csv.yaml").write_text("data: {state: {columns: [x, y]}, action: {derive: state}}\n")
    (root / "pipe.yaml").write_text("stages: [learn-a]\noutput: {plots: false}\n")
    return root, data, csv


def run(capsys, *args) -> tuple[int, dict | None, str]:
    code = main([*map(str, args), "--json", "-q"])
    out = capsys.readouterr()
    return code, json.loads(out.out) if out.out.strip() else None, out.err


@pytest.mark.parametrize("command", ["learn-a", "learn-v", "learn-pi", "run", "inspect", "convert", "predict",
                                     "evaluate", "simulate"])
def test_every_command_reads_and_writes_names_that_are_not_utf8(capsys, names, tmp_path, command):
    root, data, csv = names
    out = odd(tmp_path, b"out\xfc")
    model = odd(tmp_path, b"m\xfb")
    if command in ("predict", "evaluate"):
        assert main(["learn-v", str(data), "-o", str(model), "-q", "--n-centres", "4"]) == 0
    argv = {"learn-a": ["learn-a", data, "-o", out],
            "learn-v": ["learn-v", data, "-o", out, "--n-centres", "4"],
            "learn-pi": ["learn-pi", csv, "-c", root / "csv.yaml", "-o", out, "--n-centres", "4"],
            "run": ["run", root / "pipe.yaml", "--data", data, "-o", out],
            "inspect": ["inspect", csv],
            "convert": ["convert", csv, "-c", root / "csv.yaml", "-o", odd(tmp_path, b"c\xfa.h5")],
            "predict": ["predict", model / "model.h5", data, "-o", odd(tmp_path, b"p\xf9.csv")],
            "evaluate": ["evaluate", model / "model.h5", data, "-o", out],
            "simulate": ["simulate", "toy2d", "-o", odd(tmp_path, b"s\xf8.h5")]}[command]
    code, summary, err = run(capsys, *argv)
    assert code == 0 and summary is not None and "internal error" not in err, err
    wrote = {"convert": odd(tmp_path, b"c\xfa.h5"), "predict": odd(tmp_path, b"p\xf9.csv"),
             "simulate": odd(tmp_path, b"s\xf8.h5"), "inspect": csv}.get(command, out)
    assert wrote.exists()
    if command in ("learn-a", "learn-v", "run"):
        report = (out / "report.md").read_bytes()
        assert os.fsencode(data.name) in report  # the name's own bytes, not an escape


@pytest.mark.parametrize("suffix", [".json", ".yaml"])
def test_export_writes_such_a_name_as_an_escape_that_reads_back(capsys, names, tmp_path, suffix):
    """A model learnt from such a file, exported: the document is UTF-8 (JSON and YAML cannot
    hold the bytes), the name a \\udcNN escape that reads back to the same path."""
    import yaml

    _, data, _ = names
    model = odd(tmp_path, b"m\xfb")
    assert main(["learn-a", str(data), "-o", str(model), "-q"]) == 0
    out = odd(tmp_path, b"e\xfd" + suffix.encode())
    code, summary, err = run(capsys, "export", model / "model.h5", "-o", out)
    assert code == 0 and summary["out"] == str(out) and err == "", err
    text = out.read_bytes().decode("utf-8")  # valid UTF-8
    doc = json.loads(text) if suffix == ".json" else yaml.safe_load(text)
    assert os.fsencode(doc["source"]["file"]) == os.fsencode(model / "model.h5")
    assert main(["export", str(model / "model.h5"), "-o", str(tmp_path / f"plain{suffix}")]) == 0
    assert "wrote " + str(tmp_path / f"plain{suffix}") in capsys.readouterr().err


def test_a_missing_file_of_such_a_name_is_one_line(capsys, tmp_path):
    code, summary, err = run(capsys, "learn-a", odd(tmp_path, b"gone\xf5.h5"), "-o", tmp_path / "o")
    assert code == 2 and summary["status"] == "error"
    assert err.count("\n") == 1 and "gone\\xf5.h5: no such file" in err  # the byte, shown


def test_batch_globs_match_names_that_are_not_utf8(capsys, names, tmp_path):
    """A batch over a folder holding such a name ran no job before (the job id's digest
    encoded the name as UTF-8); now each file is a job, summarised under its own bytes."""
    root, data, _ = names
    folder = odd(tmp_path, b"logs\xe4")
    folder.mkdir()
    shutil.copy(data, folder / data.name)
    shutil.copy(data, folder / "plain.h5")
    shutil.copy(root / "pipe.yaml", folder / "pipe.yaml")
    (folder / "m.yaml").write_text("jobs:\n  - files: ['*.h5']\n    config: pipe.yaml\n")
    out = tmp_path / "b"
    code, summary, err = run(capsys, "batch", folder / "m.yaml", "-o", out, "-j", "1")
    assert code == 0 and summary["ok"] == 2, err
    assert os.fsencode(data.name) in (out / "summary.csv").read_bytes()
    code, summary, err = run(capsys, "batch", "--files", str(folder / "*.h5"), "-c", folder / "pipe.yaml",
                             "-o", out, "-j", "1")
    assert code == 0 and summary["skipped"] == 2, err
