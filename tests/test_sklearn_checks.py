"""scikit-learn's own estimator checks (``parametrize_with_checks``) on every learner.

The deliberate deviations are listed, with their reasons, in docs/sklearn.md and here, and
marked as expected failures in strict mode: a deviation that no longer fails is an error
(remove it from both lists). scikit-learn skips ``check_array_api_input`` unless
SCIPY_ARRAY_API=1 (ccl computes with NumPy only)."""

import warnings
from collections import Counter
from pathlib import Path

import pytest
from sklearn.utils.estimator_checks import check_estimator, parametrize_with_checks

from ccl_cli.learn.constraint import (
    AutoConstraint,
    ConstraintInStretches,
    KnownFeatureConstraint,
    LinearConstraint,
    PerDemonstration,
    PerSegment,
    PerWindow,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.model_selection import Tuned
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.policy import PolicyLearner

#: Every learner, small settings (the checks fit each many times on ~20–100 samples).
LEARNERS = [
    StateIndependentConstraint(),
    StateDependentConstraint(n_centres=4, n_restarts=1, tune=False),
    KnownFeatureConstraint(n_centres=4, n_restarts=1, tune=False),
    LinearConstraint(),
    PerDemonstration(LinearConstraint(regressors="identity")),
    PerWindow(),
    PerSegment(),
    ConstraintInStretches(),
    AutoConstraint(),
    NullSpaceComponent(n_centres=4, tune=False),
    PolicyLearner(n_centres=4, tune=False),
    Tuned(PolicyLearner(n_centres=4, tune=False), {"n_centres": [4, 9]}),
]

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
#: The checks that fit scikit-learn's single-column target (U (N, 1)), or data without the
#: sample times, and go on with the fitted learner.
FITS = tuple(f"check_{name}" for name in (
    "fit_score_takes_y", "estimators_overwrite_params", "dont_overwrite_parameters",
    "estimators_fit_returns_self", "readonly_memmap_input", "n_features_in_after_fitting",
    "positive_only_tag_during_fit", "estimators_dtypes", "dtype_object", "pipeline_consistency",
    "estimators_nan_inf", "estimators_pickle", "f_contiguous_array_estimator",
    "methods_sample_order_invariance", "methods_subset_invariance", "fit2d_1feature", "dict_unchanged",
    "fit_idempotent", "fit_check_is_fitted", "n_features_in", "fit2d_predict1d"))
TWO_ACTIONS = "a constraint needs q ≥ 2 action dimensions; the checks' target is one column"
NEEDS_TIME = f"{TWO_ACTIONS}, and this learner needs the sample times t, which the checks do not pass"
ARM_STATES = f"{TWO_ACTIONS}, and the arm2 features need p = 2 joint angles"

DEVIATIONS: dict[str, dict[str, str]] = {
    "StateIndependentConstraint": ACTIONS_NAMED_U,
    "LinearConstraint": ACTIONS_NAMED_U,
    "PerDemonstration": ACTIONS_NAMED_U,
    "NullSpaceComponent": PREDICTORS,
    "PolicyLearner": PREDICTORS,
    "Tuned": PREDICTORS,
    "StateDependentConstraint": dict.fromkeys(FITS, TWO_ACTIONS),
    "AutoConstraint": dict.fromkeys(FITS, TWO_ACTIONS),
    "KnownFeatureConstraint": dict.fromkeys(FITS, ARM_STATES),
    "PerWindow": dict.fromkeys(FITS, NEEDS_TIME),
    "PerSegment": dict.fromkeys(FITS, NEEDS_TIME),
    "ConstraintInStretches": dict.fromkeys(FITS, NEEDS_TIME),
}
def deviations(estimator) -> dict[str, str]:
    return DEVIATIONS[type(estimator).__name__]


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
    assert sorted(type(e).__name__ for e in LEARNERS) == sorted(DEVIATIONS)
    doc = (Path(__file__).resolve().parent.parent / "docs" / "sklearn.md").read_text()
    for name, failed in DEVIATIONS.items():
        assert f"`{name}`" in doc
        for check in failed:
            assert f"`{check}`" in doc, check


@pytest.mark.filterwarnings(f"ignore:{NOT_DERIVED}:UserWarning")
@pytest.mark.filterwarnings("ignore::sklearn.exceptions.SkipTestWarning")  # check_array_api_input
@pytest.mark.parametrize("estimator", [e for e in LEARNERS if len(deviations(e)) <= 3],
                         ids=lambda e: type(e).__name__)
def test_a_conforming_learner_passes_at_least_38_of_the_42_checks(estimator):
    """Counted by scikit-learn itself: its deviations fail, the array-API check is skipped,
    every other check passes."""
    results = check_estimator(estimator, on_fail=None, expected_failed_checks=deviations(estimator))
    status = Counter(r["status"] for r in results)
    assert len(results) == 42 and status["passed"] >= 38
    assert status["xfail"] == len(deviations(estimator)) and status["skipped"] == 1
