"""lwpi's search drops the samples whose ‖u‖ is at the noise level (issue 17.7): their direction û
is noise, yet the inconsistency error (ALGORITHMS.md §5) gives them full weight. Data: the
original library's 2-link arm tutorial (a random task row per step, noise std 0.01 on u), as in
``benchmarks/bench_tuning.py``."""

from __future__ import annotations

import sys
from pathlib import Path

import numpy as np

sys.path.insert(0, str(Path(__file__).resolve().parent.parent / "benchmarks"))

from bench_tuning import original_data, original_settings  # noqa: E402

from ccl_cli.learn import model_selection as S  # noqa: E402
from ccl_cli.learn.basis import make_basis  # noqa: E402
from ccl_cli.learn.consistency import inconsistency_error  # noqa: E402
from ccl_cli.learn.policy import NOISE_FRACTIONS, SCORED_FRACTION, PolicyLearner, rms_norm  # noqa: E402
from ccl_cli.metrics import nupe  # noqa: E402


def arm(noise: float, seed: int = 0):
    return original_data("arm", 40, noise, seed)


def test_noisy_arm_drops_noise_level_samples_and_learns_pi_far_better():
    """Seed 0 of the table's arm-40 row: the configured min_norm gives test NUPE 0.068 (the
    original's setting 0.068); dropping ‖u‖ ≤ 0.3 rms‖u‖ gives ~2e-4."""
    train, test = arm(0.01)
    model = PolicyLearner(method="lwpi", seed=0).fit(train.X, train.U, groups=train.demo)
    chosen = model.tuning_["chosen"]["min_norm"]
    assert chosen == NOISE_FRACTIONS[0] * rms_norm(train.U)
    assert model.n_used_ == int((np.linalg.norm(train.U, axis=1) > chosen).sum()) < len(train.U)
    hand = PolicyLearner(method="lwpi", **original_settings("arm", "lwpi")).fit(train.X, train.U)
    err = [nupe(test.pi, m.predict(test.X)).value for m in (model, hand)]
    assert err[0] < 0.02 * err[1], err


def test_noise_free_data_keep_every_sample():
    train, _ = arm(0.0)
    model = PolicyLearner(method="lwpi", seed=0).fit(train.X, train.U, groups=train.demo)
    grid = model.tuning_["grid"]["min_norm"]
    assert grid[0] == 1e-6 and len(grid) == 1 + len(NOISE_FRACTIONS)
    assert model.tuning_["chosen"]["min_norm"] == 1e-6 and model.n_used_ == len(train.U)


def test_every_candidate_is_scored_on_the_same_held_out_samples():
    """The search's held-out error of a candidate, by hand: fit on each training fold, the
    inconsistency error on the test fold's samples with ‖u‖ > 0.3 rms‖u‖ — for every min_norm."""
    train, _ = arm(0.01, seed=1)
    model = PolicyLearner(method="lwpi", seed=1).fit(train.X, train.U, groups=train.demo)
    folds = S.make_folds(train.demo, len(train.U), S.TUNE_FOLDS, 1)
    scored = np.linalg.norm(train.U, axis=1) > SCORED_FRACTION * rms_norm(train.U)
    rows = [r for r in model.tuning_["scores"] if "sigma2" not in r["params"]["basis"]][:3]
    rows = [r for r in model.tuning_["scores"] if "sigma2" not in r["params"]["basis"]][:2]
    assert len({r["params"]["min_norm"] for r in rows}) == 2  # the configured value and the floor
    for row in rows:
        fitted = make_basis(row["params"]["basis"], seed=1).fit(train.X)  # on all rows, as the search
        basis = {"kind": "rbf", "centres": fitted.centres_, "sigma2": fitted.sigma2_}
        learner = PolicyLearner(method="lwpi", tune=False, basis=basis, min_norm=row["params"]["min_norm"])
        errors = []
        for fit_rows, test in folds.pairs:
            fold = learner.fit(train.X[fit_rows], train.U[fit_rows])
            keep = test[scored[test]]
            errors.append(inconsistency_error(fold.predict(train.X[keep]), train.U[keep]))
        np.testing.assert_allclose(np.mean(errors), row["mean"], rtol=1e-6)


def test_the_shared_sums_give_the_fit_of_its_own_rows():
    """A candidate with a larger min_norm reuses the sums of the one before on its basis, minus
    the rows it drops: the model the search keeps equals a fit on those rows alone."""
    train, test = arm(0.01, seed=2)
    model = PolicyLearner(method="lwpi", seed=2).fit(train.X, train.U, groups=train.demo)
    chosen = model.tuning_["chosen"]
    assert chosen["min_norm"] > 1e-6
    again = PolicyLearner(method="lwpi", tune=False, seed=2, **chosen).fit(train.X, train.U)
    np.testing.assert_allclose(model.predict(test.X), again.predict(test.X), rtol=1e-8, atol=1e-10)


def test_the_search_scores_the_same_without_the_kept_features(monkeypatch):
    """Above the feature-cache bytes the search computes β per block: the same held-out errors."""
    import ccl_cli.learn.policy as policy

    train, _ = arm(0.01, seed=3)
    kept = PolicyLearner(method="lwpi", seed=3).fit(train.X, train.U, groups=train.demo).tuning_
    monkeypatch.setattr(policy, "feature_cache_bytes", lambda *arrays: 0)
    blocks = PolicyLearner(method="lwpi", seed=3).fit(train.X, train.U, groups=train.demo).tuning_
    assert blocks["chosen"] == kept["chosen"] and len(blocks["scores"]) == len(kept["scores"])
    np.testing.assert_allclose([r["mean"] for r in blocks["scores"]], [r["mean"] for r in kept["scores"]],
                               rtol=1e-9)


def test_the_report_says_which_held_out_samples_scored_the_candidates():
    from ccl_cli.render.report import tuning_markdown

    train, _ = arm(0.01)
    lwpi = PolicyLearner(method="lwpi", seed=0).fit(train.X, train.U, groups=train.demo)
    text = "\n".join(tuning_markdown("learn-pi", lwpi.tuning_))
    assert f"Held-out errors on the held-out samples with ‖u‖ > {SCORED_FRACTION:g} · rms‖u‖" in text
    pi = PolicyLearner(method="pi", seed=0).fit(train.X, train.U, groups=train.demo)
    assert "scored_on" not in pi.tuning_ and "min_norm" not in pi.tuning_["grid"]
    assert "Held-out errors on" not in "\n".join(tuning_markdown("learn-pi", pi.tuning_))
