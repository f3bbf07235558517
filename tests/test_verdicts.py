"""Verdicts of fitted stages (issue 17 item 3): a stage says "ok" only when its held-out
evidence does, against baselines; otherwise coded warnings say what is wrong, the run's status
is "poor", report.md and stderr open with the verdict, and --strict exits 1."""

from __future__ import annotations

import json

import numpy as np

from ccl_cli import diagnostics
from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.dataset import Derivative
from ccl_cli.io import write_demonstrations
from ccl_cli.learn.constraint import StateIndependentConstraint
from ccl_cli.metrics import subspace_angle


def metric(value, se=None):
    return {"name": "X", "value": value, "error": value, "normaliser": 1.0, "normaliser_of": "u", "se": se}


def test_overfit_and_baseline_checks_by_hand():
    assert diagnostics.overfit("s", "NPE", metric(1.8e-6), metric(0.54))[0]["code"] == "overfit"
    assert diagnostics.overfit("s", "NPE", metric(1e-4), metric(5e-3)) == []  # both near the noise level
    assert diagnostics.overfit("s", "NPE", metric(0.1), metric(0.5)) == []  # 5× only
    worse = diagnostics.not_better("s", "NCPE_obs", metric(1.2), 1.0, "predicting zero")
    assert worse[0]["code"] == "no_better_than_baseline" and "1.2 is no better than predicting zero" in \
        worse[0]["message"]
    assert diagnostics.not_better("s", "NCPE_obs", metric(0.3, se=0.05), 1.0, "zero") == []
    assert diagnostics.not_better("s", "NCPE_obs", metric(0.95, se=0.1), 1.0, "zero") != []  # within its SE
    assert diagnostics.status([]) == "ok" and diagnostics.status(worse) == "poor"


def test_constraint_evidence_tells_a_quiet_row_from_a_moving_one():
    d = sim.tracker_plane(duration=30.0, seed=4)
    right = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    ev = diagnostics.constraint_evidence(right, d, d.U)  # velocities of the positions: their drift
    assert ev["holds"] and ev["ratio"][0] < 5 and ev["drift"][0] < 0.05  # both tests agree
    wrong = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    wrong.A_ = np.linalg.svd(right.A_)[2][1:2]  # an in-plane direction instead of the normal
    ev = diagnostics.constraint_evidence(wrong, d, d.U)
    assert not ev["holds"] and ev["drift"][0] > 0.3 and ev["ratio"][0] > 30 and ev["measure"] == "drift"
    assert diagnostics.does_not_hold("learn-a", ev, "test data")[0]["code"] == "constraint_does_not_hold"
    # recorded actions (not the states' derivative): the motion along the rows against their noise
    recorded = d.subset(np.arange(d.n_samples))
    recorded.derivative = Derivative(False)
    recorded.X = recorded.X + np.random.default_rng(0).normal(scale=1.0, size=recorded.X.shape)
    ev = diagnostics.constraint_evidence(right, recorded, recorded.U)
    assert "drift" not in ev and ev["holds"] and ev["ratio"][0] < 5
    ev = diagnostics.constraint_evidence(wrong, recorded, recorded.U)
    assert not ev["holds"] and ev["ratio"][0] > 30



def test_constraint_evidence_of_overflowing_data_tells_nothing():
    """Observations whose squares overflow (a damaged file's 1e200s) give no evidence, not
    rows judged on NaN (does_not_hold then found no moving row: StopIteration)."""
    d = sim.tracker_plane(duration=30.0, seed=4)
    model = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    U = d.U.copy()
    U[::7] = 1e200
    with np.errstate(over="ignore", invalid="ignore"):
        assert diagnostics.constraint_evidence(model, d, U) is None

def run(capsys, tmp_path, data, stages: str, extra: str = "", *args) -> tuple[int, dict, dict, str]:
    path = write_demonstrations(tmp_path / "d.h5", data, force=True)
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{files: [{path}]}}\n{extra}stages: {stages}\n")
    out = tmp_path / "out"
    code = main(["run", str(cfg), "-o", str(out), "--force", "--json", *args])
    captured = capsys.readouterr()
    summary = json.loads(captured.out)
    metrics = json.loads((out / "metrics.json").read_text())
    return code, summary, metrics, (out / "report.md").read_text()


def test_default_pipeline_learns_the_table_from_u_and_flags_an_unidentifiable_policy(capsys, tmp_path):
    """The README's pipeline on a finger on a table: learn-a must not take learn-v's w̃ (which
    put a real table's normal 90° off): the constraint holds on the held-out u. One constraint
    gives no variation for learning π: learn-pi is worse than predicting zero and says so."""
    data = sim.tracker_plane(duration=40.0, seed=3)
    code, summary, metrics, report = run(capsys, tmp_path, data, "[learn-v, learn-a, learn-pi]")
    assert code == 0
    a = metrics["learn-a"]
    assert a["on"] == "u" and "holds on the test u" in a["on_reason"] and a["status"] == "ok"
    normal = np.asarray(a["constraint"]["plane_normal"])
    assert subspace_angle(normal[None], data.truth_per_sample("A")[0]) < 1.5
    assert metrics["learn-pi"]["status"] == "poor" and summary["status"] == "poor"
    assert summary["stages"]["learn-pi"]["status"] == "poor"
    codes = [w["code"] for w in summary["warnings"]]
    assert "no_better_than_baseline" in codes
    verdict = report.split("\n")[2]
    assert report.startswith("# ccl run\n\n**Verdict: poor: ") and "learn-pi: held-out" in verdict
    # --strict: the same run exits 1
    code, *_ = run(capsys, tmp_path, data, "[learn-a, learn-pi]", "", "--strict")
    assert code == 1


def test_a_constraint_that_does_not_hold_on_held_out_data_is_poor(capsys, tmp_path):
    data = sim.free_reach(n_demos=6, seed=1)  # free space: no constraint
    code, summary, metrics, _ = run(capsys, tmp_path, data, "[learn-a]", "learn-a: {method: nhat}\n")
    assert code == 0
    assert metrics["learn-a"]["n_constraints"] >= 1 and metrics["learn-a"]["status"] == "poor"
    found = [w for w in summary["warnings"] if w["code"] == "constraint_does_not_hold"]
    assert found and "the positions drift along learnt constraint row 1" in found[0]["message"]


def test_held_out_figures_carry_their_spread(capsys, tmp_path):
    data = sim.arm7(rows=(0, 1), n_demos=20, seed=2)
    code, _, metrics, report = run(capsys, tmp_path, data, "[learn-a]", "learn-a: {method: nhat}\n")
    assert code == 0
    test = metrics["learn-a"]["test"]["NPPE"]
    n_test = int(round(0.3 * 20))
    assert test["n_groups"] == n_test and 0 < test["se"] < test["value"] * 5
    assert f"({n_test} pieces)" in report


def test_the_verdict_is_ok_when_the_evidence_is(capsys, tmp_path):
    data = sim.tracker_plane(duration=30.0, seed=1)
    code, summary, metrics, report = run(capsys, tmp_path, data, "[learn-a]")
    assert code == 0 and summary["status"] == "ok" and metrics["learn-a"]["status"] == "ok"
    assert "**Verdict: ok" in report
