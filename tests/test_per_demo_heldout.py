"""A constraint fitted per demonstration has a held-out figure (issue 17 item 5): NPOE of blocks
held out inside every training demonstration, against the floor of the true constraint."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.constraint import LinearConstraint, PerDemonstration, StateIndependentConstraint
from ccl_cli.models import load_model, save_model


@pytest.mark.parametrize("seed", [0, 1])
def test_heldout_blocks_are_near_the_true_constraints_floor(seed, tmp_path):
    data = sim.varying_constraint(seed=seed, noise=0.05)  # a constant A of its own in each demo
    model = PerDemonstration(StateIndependentConstraint(n_constraints=1))
    model.fit(data.X, data.U, groups=data.demo)
    floor = npoe_error(data.true_projection(), data.U)  # the noise no constraint can explain
    train = npoe_error(model.projection(data.X, groups=data.demo), data.U)
    held = model.heldout_
    assert train <= floor  # fitted on these samples: at or below the floor
    assert floor < held["mean"] < 1.3 * floor and len(held["per_fold"]) == 5 and held["se"] > 0
    path = tmp_path / "m.h5"
    save_model(path, model)
    assert load_model(path)[0].heldout_ == held
    # global nhat on the same data: a single plane for 50 different ones
    glob = StateIndependentConstraint(n_constraints=1).fit(data.X, data.U)
    assert npoe_error(glob.projection(data.X), data.U) > 10 * held["mean"]


def test_the_stage_reports_the_heldout_blocks(tmp_path, capsys):
    path = tmp_path / "vc.h5"
    assert main(["simulate", "varying_constraint", "--noise", "0.05", "-o", str(path), "-q"]) == 0
    cfg = tmp_path / "c.yaml"
    cfg.write_text("learn-a: {method: nhat, per_demo: true, n_constraints: 1}\n")
    out = tmp_path / "out"
    assert main(["learn-a", str(path), "-c", str(cfg), "-o", str(out), "-q"]) == 0
    capsys.readouterr()
    entry = json.loads((out / "metrics.json").read_text())["learn-a"]
    held = entry["heldout_blocks"]["NPOE"]
    assert "test" not in entry and held["n_groups"] == 5
    assert held["value"] >= entry["train"]["NPOE"]["value"]
    assert "the held-out figure is from blocks held out inside each" in entry["per_demo_note"]
    report = (out / "report.md").read_text()
    row = f"| held-out blocks inside the training demonstrations (5 folds) | NPOE | {held['value']:.3e}"
    assert row in report
    assert np.isfinite(held["se"])


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_task_part_is_taken_out_of_the_score_and_the_heldout_blocks(seed):
    """u = A⁺b + Nπ: NPOE is of z = u − ṽ (eq. §6), so a model with a task term is judged on the
    null-space consistency, not on the task part A⁺b it explains by design."""
    data = sim.varying_constraint(seed=seed, task=True, noise=0.05)
    model = PerDemonstration(LinearConstraint(regressors="identity", task=True, n_constraints=1))
    model.fit(data.X, data.U, groups=data.demo)
    floor = npoe_error(data.true_projection(), data.U - data.truth["v"], data.U)
    without_task = npoe_error(model.projection(data.X, groups=data.demo), data.U)
    assert without_task > 15 * floor  # the task part A⁺b counted as error
    assert floor < model.held_out_error(data.X, data.U, groups=data.demo) < 2 * floor
    assert model.heldout_["mean"] < 5 * floor


def test_the_summary_shows_the_heldout_blocks(tmp_path, capsys):
    path = tmp_path / "vc.h5"
    assert main(["simulate", "varying_constraint", "--noise", "0.05", "-o", str(path), "-q"]) == 0
    cfg = tmp_path / "c.yaml"
    cfg.write_text("learn-a: {method: nhat, per_demo: true, n_constraints: 1}\n")
    capsys.readouterr()
    assert main(["learn-a", str(path), "-c", str(cfg), "-o", str(tmp_path / "out"), "--json"]) == 0
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    held = summary["stages"]["learn-a"]["heldout_blocks"]["NPOE"]
    assert summary["verdict"] == "ok: every stage's held-out evidence supports it"  # the blocks are held out
    saved = json.loads((tmp_path / "out" / "metrics.json").read_text())["learn-a"]["heldout_blocks"]
    assert held == saved["NPOE"]["value"]
