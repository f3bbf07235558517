"""Verdicts of fitted stages (issue 17 item 3): a stage says "ok" only when its held-out
evidence does, against baselines; otherwise coded warnings say what is wrong, the run's status
is "poor", report.md and stderr open with the verdict, and --strict exits 1."""

from __future__ import annotations

import json

import numpy as np
import pytest

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



def test_constraint_evidence_of_a_curved_surface_reads_its_level_not_its_integrated_rows():
    """A model of level sets measures the positions' drift by its own level h(x): integrating the
    normalised gradients of a sphere adds up their tilts over every loop (the Trakstar curved
    surface: 1.1 of the spread, "does not hold", on the right answer)."""
    from ccl_cli.learn.constraint import ManifoldConstraint, geometry

    d = sim.tracker_sphere(duration=60.0, seed=4)
    model = ManifoldConstraint(family="sphere", n_constraints=1).fit(d.X, d.U, groups=d.demo)
    ev = diagnostics.constraint_evidence(model, d, d.U)
    h = model.levels(d.X)[:, 0]
    by_hand = h.std() / np.sqrt(np.trace(np.cov(d.X.T, bias=True)))  # one demonstration
    assert ev["holds"] and ev["drift"][0] == pytest.approx(by_hand, rel=1e-9) and by_hand < 0.02
    integrated = geometry.rows_drift(model.constraint(d.X), d.X, d.demo)[0]
    assert integrated > 5 * by_hand
    model.weights_[:, 0] = model.weights_[:, -1].copy()  # the level of the widest spread instead
    ev = diagnostics.constraint_evidence(model, d, d.U)
    assert not ev["holds"] and ev["measure"] == "drift" and ev["drift"][0] > 0.5


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


# -- honest by construction (issue 30 item 5) ----------------------------------------------------
def test_angles_to_the_truth_per_sample_by_hand():
    from ccl_cli.app import truth

    e1, e2, e3 = np.eye(3)
    c, s = np.cos(np.radians(20.0)), np.sin(np.radians(20.0))
    learnt = np.array([[c * e1 + s * e2], [e1], [np.zeros(3)], [e1]])
    true = np.array([[e1], [np.zeros(3)], [np.zeros(3)], [e2]])
    deg, k_l, k_t = truth.per_sample(learnt, true)
    assert deg == pytest.approx([20.0, 90.0, 0.0, 90.0])  # rows 20° apart; a row against none; none; 90°
    assert k_l.tolist() == [1, 1, 0, 1] and k_t.tolist() == [1, 0, 0, 1]
    # the true rows from N alone: the direction I − N keeps
    n = np.array([0.6, 0.0, 0.8])
    d = sim.tracker_plane(duration=5.0, seed=0)
    d.truth = {"N": np.eye(3) - np.outer(n, n)}
    rows = truth.true_rows(d)
    assert rows.shape == (d.n_samples, 3, 3)
    assert np.linalg.matrix_rank(rows[0]) == 1
    assert subspace_angle(rows[0], n[None]) == pytest.approx(0.0, abs=1e-6)


def test_a_constraint_far_from_the_truth_in_the_file_is_poor_and_says_so(capsys, tmp_path):
    """u = v + w with a task part: learn-a on u alone finds a row 90° from the true one. Before,
    the verdict was "ok" (the row holds on the held-out u); the file's truth says otherwise."""
    data = sim.toy2d(constraint="fixed", task=True, sampling="uniform", n_samples=1000, n_demos=10, seed=0)
    code, summary, metrics, report = run(capsys, tmp_path, data, "[learn-a]")
    assert code == 0 and summary["status"] == "poor" and metrics["learn-a"]["status"] == "poor"
    found = metrics["learn-a"]["truth"]
    learnt = np.asarray(metrics["learn-a"]["constraint"]["rows"])
    angle = subspace_angle(learnt, data.truth_per_sample("A")[0])
    assert found["true_k"] == found["learnt_k"] == 1 and found["median_deg"] == pytest.approx(angle, abs=1e-6)
    assert angle > 80 and found["far"] and found["NPPE"] == metrics["learn-a"]["test"]["NPPE"]["value"]
    assert summary["stages"]["learn-a"]["truth"] == found
    assert summary["verdict"].startswith(f"poor: learn-a: the learnt constraint is {angle:.0f}° from the one "
                                         "stored in the file")
    assert "run learn-v first" in summary["verdict"]
    assert "### Against the ground truth in the file" in report
    assert "**Far off**: the learnt constraint" in report
    # after learn-v, on: auto weighs u against w̃ and learns from w̃: right, and said to be
    for spec in ("", "learn-a: {on: w}\n"):
        code, summary, *_ = run(capsys, tmp_path, data, "[learn-v, learn-a]", spec)
        found = summary["stages"]["learn-a"]["truth"]
        assert summary["status"] == "ok" and found["median_deg"] < 1.0 and not found["far"]
    # forced onto u after learn-v: the words say where the task part went
    code, summary, *_ = run(capsys, tmp_path, data, "[learn-v, learn-a]", "learn-a: {on: u}\n")
    assert summary["stages"]["learn-a"]["status"] == "poor"
    assert "learn-a on: w learns from w̃" in summary["verdict"]


def test_a_wrong_number_of_constraints_against_the_truth_is_poor(capsys, tmp_path):
    """Free reaching (no constraint: learn-a finds k = 0) in a file whose truth claims a row."""
    data = sim.free_reach(seed=0)
    data.truth = {"N": np.diag([0.0, 1.0, 1.0])}
    code, summary, metrics, _ = run(capsys, tmp_path, data, "[learn-a]")
    found = metrics["learn-a"]["truth"]
    assert found["true_k"] == 1 and found["learnt_k"] == metrics["learn-a"]["n_constraints"] == 0
    assert found["median_deg"] == 90.0 and found["k_agrees"] == 0.0
    assert summary["verdict"].startswith("poor: learn-a: 0 constraint(s) learnt, the ground truth stored in "
                                         "the file has 1")


def test_a_right_answer_against_the_truth_stays_ok(capsys, tmp_path):
    data = sim.tracker_plane(duration=30.0, seed=1)
    code, summary, metrics, report = run(capsys, tmp_path, data, "[learn-a]")
    found = metrics["learn-a"]["truth"]
    assert summary["status"] == "ok" and not found["far"] and found["true_k"] == found["learnt_k"] == 1
    normal = np.asarray(metrics["learn-a"]["constraint"]["rows"])
    angle = subspace_angle(normal, data.truth_per_sample("A")[0])
    assert found["median_deg"] == pytest.approx(angle, abs=1e-6)
    assert found["median_deg"] < 1.5 and found["part"] == "test"
    assert f"largest principal angle per sample median {found['median_deg']:.3g}°" in report


def test_a_null_space_part_far_from_the_truth_in_the_file_is_poor(capsys, tmp_path):
    """A hand opening a door (4 demonstrations, a 4-mm compliant grasp): learn-v's w̃ is
    consistent with u on the held-out demonstrations (NPE 0.27, better than u regressed with no
    task part, 1.2), so the verdict was "ok"; against the true w the file carries it is worse than
    w̃ = 0 (NUPE_w 2.0). The toy with a task part stays ok (NUPE_w 1e-4)."""
    data = sim.hinge(n_demos=4, seed=1, compliance=0.004)
    code, summary, metrics, _ = run(capsys, tmp_path, data, "[learn-v]")
    v = metrics["learn-v"]
    assert code == 0 and v["status"] == summary["status"] == "poor"
    assert v["test"]["NPE"]["value"] < v["baseline"]["test"]["NPE"]["value"]  # the NPE checks pass
    assert v["test"]["NUPE_w"]["value"] > 1.5
    nupe = v["test"]["NUPE_w"]["value"]
    assert summary["verdict"] == (f"poor: learn-v: held-out NUPE_w {nupe:.3g} against the file's true "
                                  "null-space part w is no better than w̃ = 0 (1)")
    toy = sim.toy2d(constraint="fixed", task=True, sampling="uniform", n_samples=1000, n_demos=10, seed=0)
    code, summary, metrics, _ = run(capsys, tmp_path, toy, "[learn-v]")
    assert summary["status"] == "ok" and metrics["learn-v"]["test"]["NUPE_w"]["value"] < 1e-2
    by_hand = diagnostics.nullspace_far_from_truth("s", "train", {"NUPE_w": metric(0.95, se=0.1)})
    assert by_hand[0]["code"] == "far_from_truth" and "training NUPE_w 0.95" in by_hand[0]["message"]
    assert diagnostics.nullspace_far_from_truth("s", "test", {"NUPE_w": metric(0.5, se=0.1)}) == []
    assert diagnostics.nullspace_far_from_truth("s", "test", {"NPE": metric(3.0)}) == []  # no truth


def test_held_out_support_from_the_selection_table():
    shape = {"k": 1, "scope": "global", "basis": "linear", "measure": "held-out drift", "drift": [0.02],
             "limit": 0.05, "holds": True}
    states = {"rule": "auto", "n_constraints": 1, "decided_by": "states", "geometry": {"models": [shape]}}
    found = diagnostics.heldout_support(states, None, "test")
    assert found["supported"] and "held-out drift 0.02 ≤ 0.05" in found["why"]
    winner = {"class": "nhat", "chosen": True, "k": 1, "folds": "5 folds", "rank_reason": "row 2 moves"}
    fixed = {"rule": "auto", "n_constraints": 2, "candidates": [{"class": "none", "chosen": False}, winner]}
    found = diagnostics.heldout_support(fixed, None, "test")  # asked for 2 rows, 1 found held out
    assert not found["supported"] and "the held-out rank of nhat is 1" in found["why"]
    assert diagnostics.no_heldout_support("learn-a", found)[0]["code"] == "no_heldout_support"
    assert diagnostics.heldout_support(fixed, {"holds": True}, "test")["supported"]  # the test part says so
    lone = {"rule": "auto", "n_constraints": 1, "candidates": []}  # too few samples to cross-validate
    assert "not cross-validated" in diagnostics.heldout_support(lone, None, "train")["why"]
    assert diagnostics.heldout_support({"rule": "noise", "n_constraints": 1}, None, "test") is None
    assert diagnostics.heldout_support({**states, "n_constraints": 0}, None, "test") is None


def test_degenerate_input_is_not_ok(capsys, tmp_path):
    data = sim.arm_at_rest(seed=0)
    code, summary, metrics, _ = run(capsys, tmp_path, data, "[learn-a]")
    assert code == 0 and metrics["learn-a"]["status"] == "poor"
    assert "learn-a: learnt from degenerate input: the recording does not move" in summary["verdict"]
    # a learnt w̃ of nearly nothing, and fewer samples than parameters, by hand
    d = sim.tracker_plane(duration=4.0, seed=0)
    model = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    assert diagnostics.model_parameters(model) == 2  # one row in 3-D: 1 · (3 − 1)
    tiny = d.U * 1e-3
    found = diagnostics.degenerate_input("learn-a", d, tiny, "w", model, float(d.U.var(0).sum()))
    assert "holds 1e-06 of u's variance" in found[0]["message"]
    assert diagnostics.degenerate_input("learn-a", d, d.U, "w", model, float(d.U.var(0).sum())) == []
    few = d.subset(np.arange(1))
    found = diagnostics.degenerate_input("learn-a", few, few.U, "u", model)
    assert found and "1 training samples for 2 parameters" in found[0]["message"]


def test_a_policy_with_no_metric_is_unjudged_not_ok(capsys, tmp_path):
    """learn-pi alone on data without a true π: no metric (no Ñ to compare u with, no π to compare
    π̃ with), so the stage is "unjudged" — never "ok" — says why, and --strict exits 1; the same
    data with its truth has NUPE and is judged on it."""
    data = sim.toy2d(n_demos=12, seed=3)
    bare = data.subset(np.arange(data.n_samples))
    bare.truth = {}
    code, summary, metrics, report = run(capsys, tmp_path, bare, "[learn-pi]", "", "--strict")
    assert code == 1 and summary["status"] == "unjudged" and metrics["learn-pi"]["status"] == "unjudged"
    assert not any(metrics["learn-pi"].get(split) for split in ("train", "test", "heldout_blocks"))
    assert summary["verdict"].startswith("unjudged: learn-pi: no metric to judge it by")
    assert [w["code"] for w in summary["warnings"]].count("not_judged") == 1
    assert report.startswith("# ccl run\n\n**Verdict: unjudged: ")
    assert "no metric either." in report  # its dpl baseline has none either
    code, summary, metrics, _ = run(capsys, tmp_path, data, "[learn-pi]")
    assert "NUPE" in metrics["learn-pi"]["test"] and summary["status"] in ("ok", "poor")
    assert "not_judged" not in [w["code"] for w in summary["warnings"]]
