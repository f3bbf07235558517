"""The estimator contract every learner keeps (issue 16): scikit-learn's meta-estimators
work on them, parameters are validated from one declaration, the state dimension is
checked and saved, fitting changes nothing it is given, and tuning does not depend on
the clock. Seeds are fixed."""

import inspect
import json
import time
import typing

import h5py
import numpy as np
import pytest
from sklearn.base import clone as sk_clone
from sklearn.model_selection import GridSearchCV, KFold

from ccl_cli import simulate as sim
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn.basis import RBFBasis
from ccl_cli.learn.constraint import (
    KnownFeatureConstraint,
    LinearConstraint,
    PerDemonstration,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.constraint.base import ConstraintModel
from ccl_cli.learn.model_selection import Tuned
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.params import Interval, Options, declared, forms_of, problem
from ccl_cli.learn.policy import METHODS, PolicyLearner
from ccl_cli.models import load_model, save_model

TOY = sim.toy2d(constraint="parabola", seed=0, n_demos=12)
ARM = sim.two_link(seed=0, n_demos=12, n_steps=20)
NCL = sim.toy2d(task=True, sampling="uniform", n_samples=300, seed=0)

#: (name, unfitted learner, grid, data) for every learner, each policy method and Tuned
CASES = [
    ("nhat", lambda: StateIndependentConstraint(), {"selection": ["ratio", "eigengap"]}, TOY),
    ("alpha", lambda: StateDependentConstraint(n_centres=4, n_restarts=1, tune=False),
     {"n_centres": [4, 9]}, TOY),
    ("lambda", lambda: KnownFeatureConstraint(features="arm2", n_centres=4, n_restarts=1, tune=False),
     {"n_centres": [4, 9]}, ARM),
    ("linear", lambda: LinearConstraint(), {"degree": [1, 2]}, TOY),
    ("per_demo", lambda: PerDemonstration(LinearConstraint(regressors="identity")),
     {"estimator__whiten": ["rms", "none"]}, TOY),
    ("ncl", lambda: NullSpaceComponent(n_centres=4, tune=False), {"n_centres": [4, 9]}, NCL),
    *[(m, lambda m=m: PolicyLearner(method=m, n_centres=9, tune=False), {"n_centres": [4, 9]}, TOY)
      for m in METHODS],
    ("tuned", lambda: Tuned(PolicyLearner(n_centres=4, tune=False), {"n_centres": [4, 9]}),
     {"folds": [3, 4]}, TOY),
]
IDS = [c[0] for c in CASES]


@pytest.mark.parametrize("name,make,grid,data", CASES, ids=IDS)
def test_scikit_learn_clones_and_grid_searches_every_learner(name, make, grid, data):
    est = make()
    twin = sk_clone(est)  # scikit-learn's own checks: parameters stored unchanged
    assert type(twin) is type(est) and twin.get_params(deep=False).keys() == est.get_params(deep=False).keys()
    kw = {"projections": data.true_projection()} if name == "pi-coupled" else {}
    search = GridSearchCV(est, grid, cv=3, error_score="raise").fit(data.X, data.U, **kw)
    assert search.best_params_ in [dict(zip(grid, v, strict=True)) for v in zip(*grid.values(), strict=True)]
    scores = search.cv_results_["mean_test_score"]
    assert scores.shape == (2,) and np.all(np.isfinite(scores))
    constraint = isinstance(getattr(est, "estimator", est), ConstraintModel)
    assert np.all(scores >= 0) if constraint else np.all(scores <= 0)
    refit = search.best_estimator_
    assert refit.n_features_in_ == data.n_state
    assert refit.score(data.X, data.U) == pytest.approx(search.score(data.X, data.U))


def test_grid_search_score_is_the_split_likelihood_by_hand():
    """GridSearchCV's fold scores of nhat are the split's likelihood gain of the two smallest
    directions of the training actions (constraint models' score: comparable across k), computed
    here with numpy on scikit-learn's own folds; held_out_error is their NPOE."""
    data = sim.arm7(rows=(0, 1), seed=2, n_demos=10)
    search = GridSearchCV(StateIndependentConstraint(n_constraints=2), {"threshold": [0.1]}, cv=3).fit(
        data.X, data.U)
    for i, (train, test) in enumerate(KFold(3).split(data.X)):
        vecs = np.linalg.eigh(data.U[train].T @ data.U[train])[1][:, :2]
        Ut = data.U[test]
        Ec = np.mean(np.sum((Ut @ vecs) ** 2, 1))
        Ef = np.mean(np.sum(Ut**2, 1)) - Ec
        gain = 0.5 * (7 * np.log((Ec + Ef) / 7) - 2 * np.log(Ec / 2) - 5 * np.log(Ef / 5)) / 7
        assert search.cv_results_[f"split{i}_test_score"][0] == pytest.approx(gain, rel=1e-9)
        model = StateIndependentConstraint(n_constraints=2).fit(data.X[train], data.U[train])
        npoe = Ec / np.var(Ut, axis=0, ddof=1).sum()
        assert model.held_out_error(data.X[test], Ut) == pytest.approx(npoe, rel=1e-9)


def test_a_search_over_the_number_of_constraints_finds_the_true_one():
    """−NPOE would pick one row (fewer rows always leave less motion in them); the split's
    likelihood picks the two rows the arm holds, on held-out demonstrations."""
    from sklearn import config_context
    from sklearn.model_selection import GroupKFold

    data = sim.arm7(rows=(0, 1), seed=0)
    with config_context(enable_metadata_routing=True):
        search = GridSearchCV(StateIndependentConstraint(), {"n_constraints": [1, 2, 3, 4]}, cv=GroupKFold(3),
                              error_score="raise").fit(data.X, data.U, groups=data.demo)
    assert search.best_params_ == {"n_constraints": 2}
    scores = search.cv_results_["mean_test_score"]
    assert scores[1] > 1.5 * max(scores[0], scores[2], scores[3])


# -- the declaration of parameters -----------------------------------------------------------
CLASSES = [StateIndependentConstraint, StateDependentConstraint, KnownFeatureConstraint, LinearConstraint,
           PerDemonstration, NullSpaceComponent, PolicyLearner, Tuned]


@pytest.mark.parametrize("cls", CLASSES, ids=lambda c: c.__name__)
def test_every_parameter_is_declared_by_its_annotation(cls):
    names = [p for p in inspect.signature(cls.__init__).parameters if p != "self"]
    forms = declared(cls)
    assert list(forms) == names and all(forms.values())


def test_an_annotation_is_read_as_the_forms_it_accepts():
    hint = typing.Annotated[int, Interval(1, 10)] | typing.Literal["a", "b"] | None
    assert forms_of(hint) == [Interval(1, 10, type=int), Options(str, frozenset({"a", "b"})), None]
    assert problem(11, forms_of(hint), "k") == "k must be an integer between 1 and 10, got 11"
    assert problem("c", forms_of(hint), "k") == "k must be one of a, b, got 'c'"
    assert problem(2.0, forms_of(hint), "k") == \
        "k must be an integer between 1 and 10 or one of a, b or None, got 2.0"
    assert problem(None, forms_of(hint), "k") is None and problem(10, forms_of(hint), "k") is None
    assert Interval(0, None, closed="neither").describe() == "a number > 0"
    assert Interval(0, 1, closed="right").describe() == "a number > 0 and ≤ 1"


def test_a_range_is_phrased_alike_by_the_learner_and_by_the_config(tmp_path):
    """One declaration, one phrasing: the learner's own check and the run spec's."""
    from ccl_cli.config import from_mapping

    with pytest.raises(ConfigError) as by_learner:
        StateDependentConstraint(n_centres=0).fit(TOY.X, TOY.U)
    with pytest.raises(ConfigError) as by_config:
        from_mapping({"learn-a": {"method": "alpha", "n_centres": 0}}, source="run.yaml")
    phrase = "n_centres must be an integer between 1 and 100000, got 0"
    assert by_learner.value.message == f"StateDependentConstraint: parameter {phrase}"
    assert by_config.value.message.endswith(f"learn-a.{phrase}")


@pytest.mark.parametrize("make,message", [
    (lambda: StateDependentConstraint(n_centres=0),
     "StateDependentConstraint: parameter n_centres must be an integer between 1 and 100000, got 0"),
    (lambda: StateIndependentConstraint(selection="ratoi"),
     "StateIndependentConstraint: parameter selection must be one of cv, eigengap, noise, ratio, threshold, "
     "got 'ratoi' (did you mean 'ratio'?)"),
    (lambda: PolicyLearner(tune={"bugdet": 5}),
     "PolicyLearner: parameter tune has an unknown key 'bugdet' (did you mean 'budget'?)"),
    (lambda: PolicyLearner(basis={"kind": "rbf", "sigma2": -1.0}),
     "PolicyLearner: parameter basis.sigma2 must be a number ≥ 1e-300, got -1.0"),
    (lambda: LinearConstraint(degree=11),
     "LinearConstraint: parameter degree must be an integer between 0 and 10, got 11"),
    (lambda: NullSpaceComponent(max_iter=True),
     "NullSpaceComponent: parameter max_iter must be an integer between 1 and 10000000, got True"),
])
def test_bad_parameters_are_one_config_error_from_fit(make, message):
    model = make()  # the constructor stores, fit validates
    with pytest.raises(ConfigError) as err:
        model.fit(TOY.X, TOY.U)
    assert err.value.message == message


# -- the state dimension -----------------------------------------------------------------------
@pytest.mark.parametrize("name,make,grid,data", CASES, ids=IDS)
def test_a_wrong_state_dimension_is_one_input_error(name, make, grid, data):
    kw = {"projections": data.true_projection()} if name == "pi-coupled" else {}
    model = make().fit(data.X, data.U, groups=data.demo, **kw)
    wrong = np.hstack([data.X, data.X[:, :1]])
    calls = [lambda: model.score(wrong, data.U, groups=data.demo)]
    calls.append((lambda: model.projection(wrong, groups=data.demo)) if hasattr(model, "projection") and
                 name != "tuned" else (lambda: model.predict(wrong)))
    for call in calls:
        with pytest.raises(InputError) as err:
            call()
        p = data.n_state
        assert err.value.message == f"the model expects p = {p} state dimensions, got {p + 1}"


def test_a_saved_model_records_p_and_a_version_1_file_still_loads(tmp_path):
    model = StateDependentConstraint(n_centres=9, n_restarts=1, tune=False).fit(TOY.X, TOY.U)
    path = save_model(tmp_path / "m.h5", model)
    with h5py.File(path) as f:
        assert f.attrs["schema_version"] == 2 and json.loads(f.attrs["fitted"])["n_features_in_"] == 2
    loaded, info = load_model(path)
    assert info["schema_version"] == 2 and loaded.n_features_in_ == 2
    np.testing.assert_array_equal(loaded.projection(TOY.X), model.projection(TOY.X))

    def as_version_1(src, dst):  # what version 1 wrote: no n_features_in_
        dst.write_bytes(src.read_bytes())
        with h5py.File(dst, "a") as f:
            f.attrs["schema_version"] = 1
            fitted = json.loads(f.attrs["fitted"])
            del fitted["n_features_in_"]
            f.attrs["fitted"] = json.dumps(fitted)
        return dst

    old, info = load_model(as_version_1(path, tmp_path / "v1.h5"))
    assert info["schema_version"] == 1 and old.n_features_in_ == 2  # inferred from the basis
    np.testing.assert_array_equal(old.projection(TOY.X), model.projection(TOY.X))
    nhat = save_model(tmp_path / "nhat.h5", StateIndependentConstraint().fit(TOY.X, TOY.U))
    old_nhat, _ = load_model(as_version_1(nhat, tmp_path / "nhat1.h5"))
    assert not hasattr(old_nhat, "n_features_in_")  # nothing implies p: any state dimension is taken
    assert old_nhat.projection(np.zeros((4, 5))).shape == (4, 2, 2)
    with h5py.File(path, "a") as f:  # a saved p that disagrees with the basis is refused
        f.attrs["fitted"] = json.dumps({**json.loads(f.attrs["fitted"]), "n_features_in_": 3})
    with pytest.raises(InputError, match="n_features_in_ is 3 but the model's basis or regressors take 2"):
        load_model(path)


# -- fit changes nothing it is given -------------------------------------------------------------
def test_fit_never_changes_the_objects_it_is_given():
    basis = RBFBasis(n_centres=9, seed=1)
    tune = {"budget": 50, "max_rows": 1000}
    X, U = TOY.X.copy(), TOY.U.copy()
    model = LinearConstraint(regressors="rbf", basis=basis, tune=tune).fit(X, U, groups=TOY.demo)
    assert not hasattr(basis, "centres_") and model.basis_ is not basis  # a fitted copy
    assert model.basis is basis and tune == {"budget": 50, "max_rows": 1000}
    np.testing.assert_array_equal(X, TOY.X)
    np.testing.assert_array_equal(U, TOY.U)
    again = LinearConstraint(regressors="rbf", basis=basis, tune=False).fit(X, U)
    np.testing.assert_array_equal(again.basis_.centres_, model.basis_.centres_)


def test_policy_projections_are_keyword_only():
    P = TOY.true_projection()
    with pytest.raises(TypeError):
        PolicyLearner(method="pi-coupled", tune=False).fit(TOY.X, TOY.U, P)  # noqa - positional on purpose
    with pytest.raises(TypeError):
        PolicyLearner(tune=False).fit(TOY.X, TOY.U, TOY.demo)


# -- tuning: a meta-estimator, deterministic ------------------------------------------------------
def test_tuned_is_the_learners_own_search_with_cv_results():
    learner = PolicyLearner(method="pi", n_centres=9).fit(TOY.X, TOY.U, groups=TOY.demo)
    grid = learner._tune_grid(TOY.X, TOY.U)
    search = Tuned(PolicyLearner(method="pi", n_centres=9, tune=False), grid)
    search.fit(TOY.X, TOY.U, groups=TOY.demo)
    assert search.tuning_ == learner.tuning_ and search.best_params_ == learner.tuning_["chosen"]
    np.testing.assert_array_equal(search.W_, learner.W_)  # learnt attributes of the winner
    np.testing.assert_array_equal(search.predict(TOY.X), learner.predict(TOY.X))
    results = search.cv_results_
    n = len(results["params"])
    assert n == len(learner.tuning_["scores"]) and results["rank_test_score"].min() == 1
    best = int(np.argmin(results["rank_test_score"]))
    assert results["params"][best] == search.best_params_
    best_error = min(r["mean"] for r in learner.tuning_["scores"])
    assert -results["mean_test_score"][best] == pytest.approx(best_error)
    assert learner.tuning_["budget_used"] == 3 * n and learner.tuning_["budget_unit"].startswith("fits")


def test_the_budget_counts_fits_and_binds_the_same_way_on_any_clock(monkeypatch):
    """A clock racing ahead (each reading 1000 s after the last) gives the identical model:
    nothing in the search reads the time. A budget of 7 fits runs 2 candidates of 3 folds."""
    def fits():
        small = PolicyLearner(method="pi", n_centres=9, tune={"budget": 7}).fit(TOY.X, TOY.U, groups=TOY.demo)
        alpha = StateDependentConstraint(n_restarts=1).fit(TOY.X, TOY.U, groups=TOY.demo)
        return small, alpha

    calm = fits()
    clock = iter(range(0, 10**9, 1000))
    for name in ("perf_counter", "monotonic", "time", "process_time"):
        monkeypatch.setattr(time, name, lambda: float(next(clock)))
    rushed = fits()
    assert calm[0].tuning_ == rushed[0].tuning_ and calm[1].tuning_ == rushed[1].tuning_
    assert calm[0].tuning_["budget_used"] == 6 and len(calm[0].tuning_["scores"]) == 2
    grid = calm[0]._tune_grid(TOY.X, TOY.U)  # bases × cut-offs
    assert calm[0].tuning_["skipped"] == int(np.prod([len(v) for v in grid.values()])) - 2
    np.testing.assert_array_equal(calm[0].W_, rushed[0].W_)
    for a, b in zip(calm[1].weights_, rushed[1].weights_, strict=True):
        np.testing.assert_array_equal(a, b)


# -- errors that are ValueErrors too ---------------------------------------------------------
def test_ccl_errors_are_value_errors_and_a_missing_h5_attribute_is_said_as_such(tmp_path):
    """InputError and ConfigError are ValueErrors, and no ``except ValueError`` in ccl turns
    them into another message (h5 access catches h5py's ValueErrors, not ours)."""
    from ccl_cli.io.h5.access import attr_value

    with h5py.File(tmp_path / "a.h5", "w") as f:
        f.attrs["n"] = 3
    with h5py.File(tmp_path / "a.h5", "r") as f:
        assert attr_value(f.attrs, "n", "a.h5") == 3
        with pytest.raises(ValueError) as err:
            attr_value(f.attrs, "format", "a.h5")
    assert isinstance(err.value, InputError) and err.value.message == "a.h5: attribute 'format' is missing"
    with pytest.raises(ValueError, match="parameter n_centres must be"):
        StateDependentConstraint(n_centres=0).fit(TOY.X, TOY.U)


@pytest.mark.parametrize("name,make,grid,data", [c for c in CASES if c[0] in ("alpha", "ncl", "pi", "tuned")],
                         ids=["alpha", "ncl", "pi", "tuned"])
def test_a_prediction_at_a_state_with_nan_is_one_input_error_not_a_nan_row(name, make, grid, data):
    model = make().fit(data.X, data.U)
    X = data.X[:5].copy()
    X[3, 1] = np.nan
    call = model.projection if name == "alpha" else model.predict
    with pytest.raises(InputError) as err:
        call(X)
    assert err.value.message == ("X contains NaN or inf in 1 of 5 states (first: row 3); a model predicts at "
                                 "finite states only")
    assert np.isfinite(call(X[:3])).all()
