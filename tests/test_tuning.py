"""Hyperparameter tuning by cross-validation, on by default (issue 9). Seeds fixed.

The bar: with defaults only (the YAML names the data and the method), the test error on
the original tutorials' data is no worse than the same learner with the tutorial's
hand-tuned basis (a 10×10 grid of RBFs, σ² = 0.5). The full measurement (5 seeds, every
case, ncl too) is ``benchmarks/bench_tuning.py``; the test keeps 3 seeds of three cases.
"""

import json

import numpy as np
import pytest

from ccl_cli import config as C
from ccl_cli import simulate as sim
from ccl_cli.app.stages import Pipeline
from ccl_cli.cli import main
from ccl_cli.learn.policy import PolicyLearner
from ccl_cli.metrics import nupe

TUTORIAL = {"kind": "rbf", "n_centres": 100, "centres": "grid", "sigma2": 0.5}


def tutorial_data(policy, seed):
    """The pi tutorial: 500 training + 500 test states uniform in [−1, 1]², a constraint per demo."""
    return sim.toy2d(policy=policy, vary_constraint=True, sampling="uniform", n_samples=1000, seed=seed)


def defaults_only(path, method):
    path.write_text(f"data: {{files: [data.h5]}}\nlearn-pi: {{method: {method}}}\n")
    return C.load(path)


@pytest.mark.parametrize("policy,method", [("attractor", "pi"), ("limit_cycle", "pi-weighted"),
                                           ("limit_cycle", "lwpi")])
def test_defaults_match_the_hand_tuned_tutorial(tmp_path, policy, method):
    cfg = defaults_only(tmp_path / "c.yaml", method)
    options = cfg.spec.section("learn-pi")  # the CLI leaves tune to the estimator, whose default ...
    assert options.tune is None and "tune" not in options.estimator_params(PolicyLearner)
    assert PolicyLearner().tune is True  # ... is to tune
    tuned, hand = [], []
    for seed in range(3):
        train, test = tutorial_data(policy, seed).split(0.5, seed)
        model = PolicyLearner(method=method, seed=seed).fit(train.X, train.U, groups=train.demo)
        tuned.append(nupe(test.truth["pi"], model.predict(test.X)).value)
        info = model.tuning_
        assert info["chosen"]["basis"] in info["grid"]["basis"] and len(info["scores"]) >= 2
        assert info["folds"]["kind"] == "demonstrations"
        model = PolicyLearner(method=method, basis=TUTORIAL, tune=False).fit(train.X, train.U)
        hand.append(nupe(test.truth["pi"], model.predict(test.X)).value)
    assert np.median(tuned) <= np.median(hand), (tuned, hand)


def test_the_pipeline_tunes_with_defaults_only(tmp_path):
    cfg = defaults_only(tmp_path / "c.yaml", "pi")
    data = tutorial_data("limit_cycle", 0)
    train, test = data.split(0.5, 0)
    masks = {"train": list(train.demo_ids), "test": list(test.demo_ids)}
    result = Pipeline(cfg.spec, data, masks).run(cfg.stages(["learn-pi"]))[0]
    assert result.info["tuning"]["chosen"] == result.model.tuning_["chosen"]
    hand = PolicyLearner(method="pi", basis=TUTORIAL, tune=False).fit(train.X, train.U)
    assert result.metrics["test"]["NUPE"]["value"] <= nupe(test.truth["pi"], hand.predict(test.X)).value


def test_tune_false_is_todays_fixed_behaviour_and_the_report_shows_the_curve(tmp_path, capsys):
    data = tutorial_data("limit_cycle", 0)
    fixed = PolicyLearner(method="pi", n_centres=25, tune=False).fit(data.X, data.U)
    assert fixed.tuning_ is None and fixed.basis_.n_features == 25
    again = PolicyLearner(method="pi", n_centres=25, tune=False).fit(data.X, data.U)
    np.testing.assert_array_equal(fixed.W_, again.W_)
    tuned = PolicyLearner(method="pi", n_centres=25, tune={"budget": 1.0}).fit(
        data.X, data.U, groups=data.demo)
    assert tuned.n_centres == 25  # constructor parameters are never changed by fit
    # the configured size first; pi on 2-D states searches centres on a grid (policy.GRID_DIMS)
    assert tuned.tuning_["grid"]["basis"][0] == {"kind": "rbf", "n_centres": 25, "centres": "grid"}
    assert tuned.tuning_["budget"] == 1.0

    h5 = tmp_path / "lc.h5"
    assert main(["simulate", "toy2d", "-o", str(h5), "--policy", "limit_cycle", "--vary-constraint",
                 "--sampling", "uniform", "--n-samples", "1000", "--test-fraction", "0.5", "-q"]) == 0
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data: {{files: [{h5}]}}\nlearn-pi: {{method: pi-weighted, tune: {{budget: 2}}}}\n")
    capsys.readouterr()
    assert main(["learn-pi", "-c", str(cfg), "-o", str(tmp_path / "out"), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["validation"]["kind"] == "masks"
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())
    tuning = metrics["learn-pi"]["tuning"]
    best = min(tuning["scores"], key=lambda r: r["mean"])
    assert tuning["budget"] == 2 and tuning["chosen"] == best["params"]
    report = (tmp_path / "out" / "report.md").read_text()
    assert "hyperparameters by cross-validation" in report and "**←**" in report
    cfg.write_text(f"data: {{files: [{h5}]}}\nlearn-pi: {{method: pi, tune: false, n_centres: 9}}\n")
    assert main(["learn-pi", "-c", str(cfg), "-o", str(tmp_path / "out2"), "-q"]) == 0
    assert "tuning" not in json.loads((tmp_path / "out2" / "metrics.json").read_text())["learn-pi"]


def test_too_little_data_to_tune_is_said_not_hidden():
    data = sim.two_link(seed=1, n_demos=2, n_steps=10)
    model = PolicyLearner(method="pi", n_centres=4).fit(data.X, data.U)
    assert model.tuning_["chosen"] is None and "not tuned" in model.tuning_["reason"]


# -- alpha and lambda (angle fits): their default grids ---------------------------------------
def test_lambda_tuning_on_the_two_link_arm_beats_the_fixed_basis():
    """Grid {16, 25} centres: held-out NPOE picks 25 and the test NPPE falls 20× (measured
    over seeds 0–4: median 3.2e-7 → 1.7e-9)."""
    from ccl_cli.learn.constraint import KnownFeatureConstraint
    from ccl_cli.metrics import nppe

    train, test = sim.two_link(seed=0).split(0.3, 0)
    tuned = KnownFeatureConstraint(features="arm2").fit(train.X, train.U, groups=train.demo)
    fixed = KnownFeatureConstraint(features="arm2", tune=False).fit(train.X, train.U, groups=train.demo)
    info = tuned.tuning_
    assert [c["n_centres"] for c in info["grid"]["basis"]] == [16, 25]
    assert info["chosen"]["basis"]["n_centres"] == 25 and tuned.basis_.n_features == 25
    assert fixed.tuning_ is None and fixed.basis_.n_features == 16
    err = [nppe(test.true_projection(), m.projection(test.X), test.truth["pi"], test.U).value
           for m in (tuned, fixed)]
    assert err[0] < 0.2 * err[1] and err[0] < 5e-8, err


def test_lambda_tuning_on_the_7dof_arm_picks_from_its_grid():
    """The 7-DoF arm with one centre (as configs/kuka_bag.yaml): grid {1, 4}, folds by demonstration."""
    from ccl_cli.learn.constraint import KnownFeatureConstraint

    data = sim.arm7(rows=(0, 1), constraint="jacobian", seed=0, n_demos=12, n_steps=20)
    model = KnownFeatureConstraint(features={"arm": "arm7", "rows": [0, 1, 2]}, n_centres=1,
                                   n_restarts=1).fit(data.X, data.U, groups=data.demo)
    info = model.tuning_
    assert [c["n_centres"] for c in info["grid"]["basis"]] == [1, 4]
    assert info["chosen"] in [r["params"] for r in info["scores"]] and len(info["scores"]) == 2
    assert info["folds"]["kind"] == "demonstrations"
    assert all(np.isfinite(r["mean"]) and r["mean"] < 1e-3 for r in info["scores"])
    N = model.projection(data.X)
    np.testing.assert_allclose(N, np.swapaxes(N, 1, 2), atol=1e-10)


def test_alpha_grid_runs_from_the_smallest_basis_up_and_finds_the_finer_one():
    """Parabola, 2000 states uniform in the box (one recording, so time-block folds): the grid
    {25, 9, 36 centres at ¼ of the default width} runs from 9 centres up; held-out NPOE falls at
    each step and 36 narrow centres win, with half the test NPPE of the untuned 25 (measured
    over 10 draws at N = 1e4: median 0.0019 against 0.0049, and the worst draw 1.08× the median
    against 1.28×; docs/measurements.md)."""
    from ccl_cli.learn.constraint import StateDependentConstraint
    from ccl_cli.metrics import nppe

    data = sim.toy2d(constraint="parabola", sampling="uniform", n_samples=7000, n_demos=1, seed=1)
    train, test = data.subset(np.arange(2000)), data.subset(np.arange(2000, 7000))
    model = StateDependentConstraint(seed=1)
    grid = model._tune_grid(train.X, train.U)["basis"]
    assert [(c["n_centres"], "sigma2" in c) for c in grid] == [(25, False), (9, False), (36, True)]
    model.fit(train.X, train.U, groups=train.demo)
    info = model.tuning_
    run = [r["params"]["basis"]["n_centres"] for r in info["scores"]]
    means = [r["mean"] for r in info["scores"]]
    assert run == [9, 25, 36] and means[0] > means[1] > means[2] and info["stopped"] is None
    assert info["chosen"]["basis"] == grid[2] and model.basis_.n_features == 36
    untuned = StateDependentConstraint(seed=1, tune=False).fit(train.X, train.U)
    err = [nppe(test.true_projection(), m.projection(test.X), test.truth["pi"], test.U).value
           for m in (model, untuned)]
    assert err[0] < 0.6 * err[1] and err[0] < 0.004, err


def test_alpha_and_lambda_with_too_few_samples_for_any_candidate_fit_as_given():
    """16 samples in 8 demonstrations: no grid basis fits in (≤ N/2 centres), so there is no
    grid and the configured basis is fitted (no 'no candidate' error)."""
    from ccl_cli.learn.constraint import KnownFeatureConstraint, StateDependentConstraint

    toy = sim.toy2d(constraint="parabola", seed=0, n_demos=8, n_steps=2)
    arm = sim.two_link(seed=0, n_demos=8, n_steps=2)
    assert toy.n_samples == arm.n_samples == 16
    alpha = StateDependentConstraint(n_centres=12).fit(toy.X, toy.U, groups=toy.demo)
    lam = KnownFeatureConstraint(features="arm2", n_centres=12).fit(arm.X, arm.U, groups=arm.demo)
    for model in (alpha, lam):
        assert model.tuning_ is None and model.basis_.n_features == 12
        assert np.isfinite(model.projection(toy.X if model is alpha else arm.X)).all()


def test_ncl_default_grid_beats_the_tutorials_16_centres():
    """ncl tutorial (ALGORITHMS.md §7: limit cycle + task part, 500/500, 16 RBFs by hand):
    the default grid K ∈ {16, 36, 64, 100} is no worse in the median of 3 seeds."""
    from ccl_cli.learn.nullspace import NullSpaceComponent

    tuned, hand = [], []
    for seed in range(3):
        data = sim.toy2d(policy="limit_cycle", task=True, sampling="uniform", n_samples=1000, seed=seed)
        train, test = data.split(0.5, seed)
        model = NullSpaceComponent(seed=seed).fit(train.X, train.U, groups=train.demo)
        assert [b["n_centres"] for b in model.tuning_["grid"]["basis"]] == [16, 36, 64, 100]
        assert model.tuning_["chosen"]["basis"]["n_centres"] == model.basis_.n_features
        tuned.append(nupe(test.truth["w"], model.predict(test.X)).value)
        model = NullSpaceComponent(n_centres=16, seed=seed, tune=False).fit(train.X, train.U)
        assert model.tuning_ is None
        hand.append(nupe(test.truth["w"], model.predict(test.X)).value)
    assert np.median(tuned) <= np.median(hand), (tuned, hand)
    fixed = NullSpaceComponent(basis={"kind": "rbf", "n_centres": 9, "sigma2": 0.5}).fit(train.X, train.U)
    assert fixed.tuning_ is None and fixed.basis_.n_features == 9  # a basis the user fixed


def test_ncl_defaults_match_the_hand_tuned_100_centres_on_the_two_link_arm():
    """ncl on the 2-link arm with a task part (b ~ U(−1, 1) per demonstration, 30 % of the
    demonstrations held out): the defaults are no worse than the hand-tuned 100 centres, median
    of 5 seeds (measured: 5.45e-5 both, 100 centres chosen in 4 of 5 seeds and 36 in the fifth,
    which is better there; the untuned 16 centres 8.9e-4). Grid and folds are the defaults."""
    from ccl_cli.learn.nullspace import NullSpaceComponent

    tuned, hand = [], []
    for seed in range(5):
        train, test = sim.two_link(task=True, seed=seed).split(0.3, seed)
        model = NullSpaceComponent(seed=seed, tune={"budget": 600}).fit(train.X, train.U, groups=train.demo)
        info = model.tuning_  # the whole grid ran, or the search says why larger bases did not
        assert len(info["scores"]) >= 3 and (info["skipped"] == 0) != bool(info["stopped"])
        tuned.append(nupe(test.truth["w"], model.predict(test.X)).value)
        model = NullSpaceComponent(n_centres=100, seed=seed, tune=False).fit(train.X, train.U)
        hand.append(nupe(test.truth["w"], model.predict(test.X)).value)
    assert np.median(tuned) <= np.median(hand), (tuned, hand)


def test_large_data_is_tuned_on_a_seeded_subset_and_the_winner_fitted_on_all():
    """Above max_rows the grid is searched on whole demonstrations (or spread pieces of one
    recording) drawn with the seed; the chosen basis is refitted on every sample."""
    from ccl_cli.learn.model_selection import tuning_subset

    many = np.repeat(np.arange(40), 100)  # 40 demonstrations of 100 samples
    rows, groups, note = tuning_subset(many, len(many), seed=3, max_rows=1000)
    assert 500 <= len(rows) <= 1000 and len(np.unique(groups)) >= 5
    assert all(np.sum(many[rows] == g) == 100 for g in np.unique(groups))  # whole demonstrations
    np.testing.assert_array_equal(tuning_subset(many, len(many), 3, 1000)[0], rows)  # seeded
    assert "whole demonstrations (seed 3)" in note
    assert tuning_subset(many, len(many), 3, 4000) is None
    rows, groups, note = tuning_subset(None, 50_000, seed=0, max_rows=2000)
    assert len(rows) == 2000 and rows.min() == 0 and rows.max() == 49_999
    assert np.all(np.diff(rows)[np.diff(groups) == 0] == 1)  # contiguous pieces
    assert len(np.unique(groups)) == 10 and "contiguous pieces" in note

    data = tutorial_data("attractor", 0)
    model = PolicyLearner(method="pi", tune={"max_rows": 400}).fit(data.X, data.U, groups=data.demo)
    assert "of 1000 samples" in model.tuning_["subset"]
    assert model.basis_.n_features == model.tuning_["chosen"]["basis"]["n_centres"]
    full = PolicyLearner(method="pi", tune=False, **model.tuning_["chosen"]).fit(data.X, data.U)
    np.testing.assert_allclose(model.W_, full.W_)  # the winner is fitted on all samples


def test_tuned_alpha_is_robust_over_training_draws():
    """Issue 19.4: the default alpha's worst of 10 training draws is within 1.5× the median
    test error (uniform parabola, 2000 samples per draw; measured at N = 1e4 and 1e5: 1.08× and
    1.07×, against 1.28× and 2.38× for the fixed 25 centres, whose placement decides)."""
    from ccl_cli.learn.constraint import StateDependentConstraint
    from ccl_cli.metrics import nppe

    errs = []
    for seed in range(10):
        data = sim.toy2d(constraint="parabola", sampling="uniform", n_samples=5000, n_demos=1, seed=seed)
        train, test = data.subset(np.arange(2000)), data.subset(np.arange(2000, 5000))
        model = StateDependentConstraint(seed=seed).fit(train.X, train.U, groups=train.demo)
        errs.append(nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U).value)
    assert max(errs) <= 1.5 * np.median(errs) and np.median(errs) < 0.004, errs
