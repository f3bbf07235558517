"""scikit-learn's own estimator checks (``parametrize_with_checks``) on every learner.

The deliberate deviations are listed, with their reasons, in docs/sklearn.md and here, and
marked as expected failures in strict mode: a deviation that no longer fails is an error
(remove it from both lists). scikit-learn skips ``check_array_api_input`` unless
SCIPY_ARRAY_API=1 (ccl computes with NumPy only)."""

import re
import warnings
from collections import Counter
from pathlib import Path

import numpy as np
import pytest
from sklearn.utils.estimator_checks import check_estimator, parametrize_with_checks

from ccl_cli.cli import main
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn.constraint import (
    AutoConstraint,
    ConstraintInStretches,
    KnownFeatureConstraint,
    LinearConstraint,
    ManifoldConstraint,
    PerDemonstration,
    PerSegment,
    PerWindow,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.constraint.base import ONE_ACTION
from ccl_cli.learn.model_selection import Tuned
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.policy import PolicyLearner
from ccl_cli.models import load_model, save_model


class OneLinkArm:
    """Φ of a one-joint planar arm (unit link): the hand's velocity per joint velocity,
    ∂(cos θ, sin θ)/∂θ = (−sin θ, cos θ)ᵀ at θ = x₀ — (N, 2, 1): features that fit the checks'
    data (one action column, any p ≥ 1), as the built-in ``arm2`` (p = q = 2) does not."""

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return np.stack([-np.sin(X[:, 0]), np.cos(X[:, 0])], 1)[:, :, None]

    def __repr__(self) -> str:
        return "OneLinkArm()"


#: Every learner, small settings (the checks fit each many times on ~20–100 samples);
#: lambda twice: with features that fit the checks' data and with the built-in ``arm2``.
LEARNERS = [
    StateIndependentConstraint(),
    StateDependentConstraint(n_centres=4, n_restarts=1, tune=False),
    KnownFeatureConstraint(features=OneLinkArm(), n_centres=4, n_restarts=1, tune=False),
    KnownFeatureConstraint(n_centres=4, n_restarts=1, tune=False),
    LinearConstraint(),
    PerDemonstration(LinearConstraint(regressors="identity")),
    PerWindow(),
    PerSegment(),
    ConstraintInStretches(),
    AutoConstraint(),
    ManifoldConstraint(),
    NullSpaceComponent(n_centres=4, tune=False),
    PolicyLearner(n_centres=4, tune=False),
    Tuned(PolicyLearner(n_centres=4, tune=False), {"n_centres": [4, 9]}),
]


def label(estimator) -> str:
    """The learner's class name; ``KnownFeatureConstraint(arm2)`` for lambda with the built-in arm."""
    name = type(estimator).__name__
    return f"{name}(arm2)" if getattr(estimator, "features", None) == "arm2" else name


#: Every learner: the actions are U, not y (docs/sklearn.md, "Deviations").
ACTIONS_NAMED_U = {
    "check_fit_score_takes_y": "fit(X, U): the second argument is U, the actions",
    "check_n_features_in_after_fitting": "it calls score(X, y=...) by keyword; score takes U",
}
#: Learners with predict (w̃, π̃): scikit-learn's own NotFittedError class.
PREDICTORS = {
    **ACTIONS_NAMED_U,
    "check_estimators_unfitted": "ccl's NotFittedError is a LearningError, not scikit-learn's class",
}
#: The checks that fit on states of a random width p (1 to 10 columns) and one action column, and
#: go on with the fitted learner: bad input for a learner whose data shape a parameter or its
#: premise fixes (each meets an InputError / ConfigError, both ValueErrors).
FITS = tuple(f"check_{name}" for name in (
    "fit_score_takes_y", "estimators_overwrite_params", "dont_overwrite_parameters",
    "estimators_fit_returns_self", "readonly_memmap_input", "n_features_in_after_fitting",
    "positive_only_tag_during_fit", "estimators_dtypes", "dtype_object", "pipeline_consistency",
    "estimators_nan_inf", "estimators_pickle", "f_contiguous_array_estimator",
    "methods_sample_order_invariance", "methods_subset_invariance", "dict_unchanged",
    "fit_idempotent", "fit_check_is_fitted", "n_features_in", "fit2d_predict1d"))
ARM2 = "the arm2 features need p = 2 joint angles and q = 2 joint velocities; the checks give 1–10 and 1"
STATES_AND_VELOCITIES = "the manifold needs p = q (positions and their velocities); the checks give p ≠ q = 1"

DEVIATIONS: dict[str, dict[str, str]] = {
    **dict.fromkeys(("StateIndependentConstraint", "StateDependentConstraint", "KnownFeatureConstraint",
                     "LinearConstraint", "PerDemonstration", "PerWindow", "PerSegment",
                     "ConstraintInStretches", "AutoConstraint"), ACTIONS_NAMED_U),
    "NullSpaceComponent": PREDICTORS,
    "PolicyLearner": PREDICTORS,
    "Tuned": PREDICTORS,
    # p = 1 too: "1 feature(s)" is not in its error, which names the arm's 2 joint angles
    "KnownFeatureConstraint(arm2)": dict.fromkeys((*FITS, "check_fit2d_1feature"), ARM2),
    # p = q = 1 passes (no constraint on one dimension)
    "ManifoldConstraint": dict.fromkeys(FITS, STATES_AND_VELOCITIES),
}
#: The configurations whose data shape a parameter or the model's premise fixes: the only ones
#: below the bar of 38 checks (docs/sklearn.md).
SHAPE_BOUND = {"KnownFeatureConstraint(arm2)", "ManifoldConstraint"}


def deviations(estimator) -> dict[str, str]:
    return DEVIATIONS[label(estimator)]


#: scikit-learn warns that the learners do not derive from its BaseEstimator: ccl does not
#: depend on scikit-learn (docs/sklearn.md).
NOT_DERIVED = "Estimator .* does not inherit from `sklearn.base.BaseEstimator`"
with warnings.catch_warnings():
    warnings.filterwarnings("ignore", NOT_DERIVED, UserWarning)
    CHECKS = parametrize_with_checks(LEARNERS, expected_failed_checks=deviations, xfail_strict=True)


@CHECKS
def test_scikit_learn_checks(estimator, check):
    check(estimator)


def test_every_learner_is_checked_and_every_deviation_is_documented():
    assert sorted(label(e) for e in LEARNERS) == sorted(DEVIATIONS)
    doc = (Path(__file__).resolve().parent.parent / "docs" / "sklearn.md").read_text()
    for name, failed in DEVIATIONS.items():
        assert f"`{name}`" in doc
        for check in failed:
            assert f"`{check}`" in doc, check


@pytest.mark.filterwarnings(f"ignore:{NOT_DERIVED}:UserWarning")
@pytest.mark.filterwarnings("ignore::sklearn.exceptions.SkipTestWarning")  # check_array_api_input
@pytest.mark.parametrize("estimator", LEARNERS, ids=label)
def test_checks_counted_by_scikit_learn(estimator):
    """Counted by scikit-learn itself: its deviations fail, the array-API check is skipped, every
    other check passes — at least 38 of the 42 on every learner but the shape-bound two."""
    dev = deviations(estimator)
    results = check_estimator(estimator, on_fail=None, expected_failed_checks=dev)
    status = Counter(r["status"] for r in results)
    assert len(results) == 42 and status["skipped"] == 1
    assert [r["check_name"] for r in results if r["status"] == "xfail"] == \
        [r["check_name"] for r in results if r["check_name"] in dev]
    assert status["passed"] == 41 - status["xfail"]
    assert (status["passed"] >= 38) == (label(estimator) not in SHAPE_BOUND)


# -- what the generic checks exercise: one action dimension, no sample times ----------------------
def one_dimensional_motion(n: int = 200):
    """Two demonstrations of a 1-D motion x(t) = sin(2t + φ) (positions X (n, 1), velocities
    U (n, 1), ids, times 0.02 s apart): it moves far above any noise, so a row on it is wrong."""
    t = np.tile(np.arange(n // 2) * 0.02, 2)
    g = np.repeat([0, 1], n // 2)
    phase = 0.7 * g
    return np.sin(2 * t + phase)[:, None], 2 * np.cos(2 * t + phase)[:, None], g, t


ONE_ACTION_LEARNERS = [
    StateIndependentConstraint(), StateIndependentConstraint(selection="threshold"), LinearConstraint(),
    LinearConstraint(regressors="rbf", task=True), StateDependentConstraint(),
    KnownFeatureConstraint(features=OneLinkArm()), PerWindow(), PerSegment(), ConstraintInStretches(),
    AutoConstraint(), ManifoldConstraint()]


@pytest.mark.parametrize("estimator", ONE_ACTION_LEARNERS, ids=repr)
def test_one_action_dimension_takes_no_constraint(estimator, tmp_path):
    """q = 1: a row would forbid all motion (before: nhat and linear answered A = [[1]], Ñ = 0,
    on this moving data; the others refused the data): k = 0, Ñ = I exactly, the reason said,
    the same after a model file's round trip (lambda's Φ here is a callable, not saved)."""
    X, U, g, t = one_dimensional_motion()
    model = estimator.fit(X, U, groups=g, t=t)
    assert model.n_constraints_ == 0 and model.selection_["reason"] == ONE_ACTION
    assert model.constraint(X, groups=g, t=t).shape == (200, 0, 1)
    assert np.array_equal(model.projection(X, groups=g, t=t), np.ones((200, 1, 1)))
    assert model.score(X, U, groups=g, t=t) == 0.0 and model.held_out_error(X, U, groups=g, t=t) == 0.0
    assert getattr(model, "tuning_", None) is None  # nothing to tune (rbf linear, alpha's default)
    if isinstance(estimator, KnownFeatureConstraint):
        return  # a Python callable Φ is not saved (ccl_cli.models)
    save_model(tmp_path / "m.h5", model)
    loaded, _ = load_model(tmp_path / "m.h5")
    assert np.array_equal(loaded.projection(X, groups=g, t=t), np.ones((200, 1, 1)))


def test_one_action_dimension_needs_no_times():
    """The learners per window / segment / stretch place no rows in time at q = 1: fitted and
    scored without t (as the checks do), one piece per demonstration."""
    X, U, g, _ = one_dimensional_motion()
    for est in (PerWindow(), PerSegment(), ConstraintInStretches()):
        model = est.fit(X, U, groups=g)
        assert model.n_constraints_ == 0 and model.score(X, U, groups=g) == 0.0
    assert PerWindow().fit(X, U, groups=g).windows_.tolist() == [[0, 0], [1, 0]]
    assert PerSegment().fit(X, U, groups=g).windows_.tolist() == [[0, 0, 1], [1, 0, 1]]
    assert ConstraintInStretches().fit(X, U, groups=g).blocks_.tolist() == [[0, 0, 0], [1, 0, 0]]


def test_rows_fixed_on_one_action_dimension():
    """A fixed n_constraints ≥ 1 at q = 1 asks for a row that forbids all motion: a ConfigError
    (a ValueError) from the learners that leave motion free; nhat keeps its fixed rule (up to q
    rows, as at any q): A = [[1]], Ñ = 0."""
    X, U, g, t = one_dimensional_motion()
    for est in (StateDependentConstraint(n_constraints=1), KnownFeatureConstraint(features=OneLinkArm(),
                n_constraints=1), PerWindow(n_constraints=1), ConstraintInStretches(n_constraints=1),
                AutoConstraint(n_constraints=1), ManifoldConstraint(n_constraints=1)):
        with pytest.raises(ValueError, match=r"^n_constraints = 1 on one action dimension: .* = 0\)$"):
            est.fit(X, U, groups=g, t=t)
    assert AutoConstraint(n_constraints=0).fit(X, U, groups=g, t=t).n_constraints_ == 0
    nhat = StateIndependentConstraint(n_constraints=1).fit(X, U)
    assert nhat.A_.tolist() == [[1.0]] and nhat.projection(X)[0, 0, 0] == 0.0


def test_without_times_a_timed_learner_names_t():
    """q ≥ 2 without t: the windows, segments and blocks are in seconds; no times are made up
    from the sample index (a 4-s window would be 4 samples) — one line naming t. A window per
    demonstration needs none."""
    rng = np.random.default_rng(0)
    X, U = rng.normal(size=(80, 2)), rng.normal(size=(80, 2))
    for est, what in ((PerWindow(), "one constraint per 4-s window"),
                      (PerSegment(), "one constraint per segment (cut where the constraint changes)"),
                      (ConstraintInStretches(), "a constraint in stretches")):
        with pytest.raises(InputError, match=rf"^{re.escape(what)} needs the sample times t"):
            est.fit(X, U)
    assert PerWindow(window=None).fit(X, U).windows_.tolist() == [[0, 0]]


def test_lambda_features_that_do_not_fit_the_data():
    """The built-in arm2 fixes p = 2 joint angles and q = 2 joint velocities: other data are bad
    input (ValueErrors), in one line."""
    rng = np.random.default_rng(0)
    with pytest.raises(InputError, match="^features arm2 need the 2 joint angles of the arm per sample "
                                         r"\(state of 2 columns\), got 3 columns$"):
        KnownFeatureConstraint().fit(rng.normal(size=(50, 3)), rng.normal(size=(50, 2)))
    with pytest.raises(ConfigError, match=r"^the features give Φ \(r, q\) = \(2, 2\) for q = 2 actions; "
                                          "U has q = 1$"):
        KnownFeatureConstraint().fit(rng.normal(size=(50, 2)), rng.normal(size=(50, 1)))


def test_the_command_line_refuses_one_action_column(tmp_path, capsys):
    """learn-a on a recording of one action column: the learners would answer k = 0 by
    construction, which no recording can tell; the command says so in one line (exit 2), with
    every method, as before."""
    X, _, g, t = one_dimensional_motion()
    for i in (0, 1):
        m = g == i
        np.savetxt(tmp_path / f"d{i}.csv", np.c_[t[m], X[m]], delimiter=",", header="t,x", comments="")
    config = tmp_path / "c.yaml"
    config.write_text("data:\n  files: [d0.csv, d1.csv]\n  time: {column: t}\n  state: {columns: [x]}\n"
                      "  action: {derive: state}\n")
    for method in ("auto", "nhat", "linear", "manifold"):
        out = tmp_path / method
        assert main(["learn-a", "-c", str(config), "-o", str(out), "--method", method, "-q"]) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err[-1] == ("ccl: error: learning a constraint needs at least 2 action dimensions (a "
                           "constraint row on one would forbid all motion)")
        assert not out.exists()
