"""scikit-learn's metadata routing (issue 27): with routing on, the demonstration ids and the
sample times reach ``fit`` and ``score`` of every learner under ``GridSearchCV`` and
``cross_validate``, each fold getting its own part — checked against fits by hand on the same
folds. ccl itself never imports scikit-learn."""

import subprocess
import sys
from dataclasses import replace

import numpy as np
import pytest
import sklearn
from sklearn.base import clone as sk_clone
from sklearn.model_selection import GridSearchCV, GroupKFold, cross_validate

from ccl_cli import simulate as sim
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn import constraint as C
from ccl_cli.learn.base import clone
from ccl_cli.learn.constraint.base import ConstraintModel
from ccl_cli.learn.model_selection import Tuned
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.policy import METHODS, PolicyLearner

TOY = sim.toy2d(constraint="parabola", seed=0, n_demos=12)
ARM = sim.two_link(seed=0, n_demos=12, n_steps=20)
NCL = sim.toy2d(task=True, n_demos=12, seed=0)
PLANE = sim.tracker_plane(duration=12.0, n_recordings=3, seed=1)
_TILT = sim.tracker_tilt(seed=1, duration=36.0)
TILT = replace(_TILT, demo=(_TILT.t // 12).astype(int), t=_TILT.t % 12)  # three 12-s demonstrations
WIPE = sim.arm_wipe(n_demos=3, seed=1)

#: (name, unfitted learner, grid, data): every learner, each policy method and Tuned
CASES = [
    ("nhat", lambda: C.StateIndependentConstraint(), {"selection": ["ratio", "eigengap"]}, PLANE),
    ("alpha", lambda: C.StateDependentConstraint(n_centres=4, n_restarts=1, tune=False),
     {"n_centres": [4, 9]}, TOY),
    ("lambda", lambda: C.KnownFeatureConstraint(features="arm2", n_centres=4, n_restarts=1, tune=False),
     {"n_centres": [4, 9]}, ARM),
    ("linear", lambda: C.LinearConstraint(), {"degree": [1, 2]}, TOY),
    ("none", lambda: C.NoConstraint(), {}, PLANE),
    ("per_demo", lambda: C.PerDemonstration(C.StateIndependentConstraint(n_constraints=1)),
     {"heldout": [False, True]}, PLANE),
    ("per_window", lambda: C.PerWindow(), {"window": [3.0, 6.0]}, TILT),
    ("per_segment", lambda: C.PerSegment(), {"penalty": [2.0, 4.0]}, TILT),
    ("stretches", lambda: C.ConstraintInStretches(), {"block": [0.5, 1.0]}, WIPE),
    ("auto", lambda: C.AutoConstraint(), {"cv_folds": [3]}, PLANE),
    ("manifold", lambda: C.ManifoldConstraint(), {"family": ["linear", "sphere"]}, PLANE),
    ("ncl", lambda: NullSpaceComponent(n_centres=4, tune=False), {"n_centres": [4, 9]}, NCL),
    *[(m, lambda m=m: PolicyLearner(method=m, n_centres=9, tune=False), {"n_centres": [4, 9]}, TOY)
      for m in METHODS],
    ("tuned", lambda: Tuned(PolicyLearner(n_centres=4, tune=False), {"n_centres": [4, 9]}),
     {"folds": [3, 4]}, TOY),
]
IDS = [c[0] for c in CASES]


@pytest.fixture(autouse=True)
def routing():
    with sklearn.config_context(enable_metadata_routing=True):
        yield


def metadata(name, d) -> dict:
    out = {"groups": d.demo, "t": d.t}
    if name == "pi-coupled":
        out["projections"] = d.true_projection()
    return out


@pytest.mark.parametrize("name,make,grid,data", CASES, ids=IDS)
def test_grid_search_by_demonstration_with_times_on_every_learner(name, make, grid, data):
    search = GridSearchCV(make(), grid, cv=GroupKFold(3), error_score="raise").fit(data.X, data.U,
                                                                                   **metadata(name, data))
    n = int(np.prod([len(v) for v in grid.values()]))
    scores = search.cv_results_["mean_test_score"]
    assert scores.shape == (n,) and np.isfinite(scores).all()
    # constraint models score the split's likelihood gain (≥ 0), the others minus an error
    constraint = isinstance(getattr(make(), "estimator", make()), ConstraintModel)
    assert (scores >= 0).all() if constraint else (scores <= 0).all()
    assert search.best_params_ in search.cv_results_["params"]
    best = search.best_estimator_
    assert best.n_features_in_ == data.n_state
    if hasattr(best, "local_to") and best.local_to is not None:  # refitted with every demonstration's ids
        assert best.applies_to(data.X, data.U, groups=data.demo, t=data.t, new_recording=False).note is None


def test_each_fold_gets_its_own_demonstrations_and_times():
    """The per-window fold scores GridSearchCV reports are those of a fit on each training part
    with its ids and times, scored on the test part with its own, computed here."""
    search = GridSearchCV(C.PerWindow(n_constraints=1), {"window": [3.0, 6.0]}, cv=GroupKFold(3)).fit(
        TILT.X, TILT.U, groups=TILT.demo, t=TILT.t)
    for i, (train, test) in enumerate(GroupKFold(3).split(TILT.X, groups=TILT.demo)):
        for j, window in enumerate((3.0, 6.0)):
            model = C.PerWindow(window=window, n_constraints=1).fit(
                TILT.X[train], TILT.U[train], groups=TILT.demo[train], t=TILT.t[train])
            by_hand = model.score(TILT.X[test], TILT.U[test], groups=TILT.demo[test], t=TILT.t[test])
            assert search.cv_results_[f"split{i}_test_score"][j] == pytest.approx(by_hand, rel=1e-12)
    # the test demonstrations were not seen in fit: scored as the model applies to them, its
    # stated rule (rows fitted on their own windows, one row each) — a clear gain over no rows
    assert all(s > 0.1 for s in search.cv_results_["mean_test_score"])


def test_cross_validate_passes_groups_and_times_as_params():
    learner = C.PerSegment(n_constraints=1)
    params = {"groups": TILT.demo, "t": TILT.t}
    result = cross_validate(learner, TILT.X, TILT.U, cv=GroupKFold(3), params=params)
    for score, (train, test) in zip(result["test_score"], GroupKFold(3).split(TILT.X, groups=TILT.demo),
                                    strict=True):
        fitted = clone(learner).fit(TILT.X[train], TILT.U[train], groups=TILT.demo[train], t=TILT.t[train])
        assert score == pytest.approx(fitted.score(TILT.X[test], TILT.U[test], groups=TILT.demo[test],
                                                   t=TILT.t[test]), rel=1e-12)


def test_requests_can_be_changed_cloned_and_are_checked():
    learner = C.PerWindow().set_fit_request(t=False)
    for twin in (clone(learner), sk_clone(learner)):
        routing = twin.get_metadata_routing()
        assert routing.fit.requests == {"groups": True, "t": False, "derivative": True}
        assert routing.score.requests == {"groups": True, "t": True}
    with pytest.raises(InputError, match="needs the sample times t"):  # t requested by score only
        GridSearchCV(learner, {"window": [3.0]}, cv=GroupKFold(3), error_score="raise").fit(
            TILT.X, TILT.U, groups=TILT.demo, t=TILT.t)
    with pytest.raises(ConfigError, match="PerWindow.fit takes no 'weights'"):
        C.PerWindow().set_fit_request(weights=True)
    assert PolicyLearner().get_metadata_routing().score.requests == {"groups": True, "projections": True,
                                                                      "t": True}
    assert Tuned(C.PerWindow(), {"window": [3.0]}).get_metadata_routing().fit.requests == {
        "groups": True, "t": True, "derivative": True}


def test_ccl_never_imports_scikit_learn():
    """A fit, a score and the metadata a learner takes — without scikit-learn in the process."""
    code = ("import sys\n"
            "from ccl_cli import simulate as sim\n"
            "from ccl_cli.learn.constraint import AutoConstraint, PerWindow\n"
            "import ccl_cli.cli, ccl_cli.app.stages\n"
            "d = sim.tracker_tilt(seed=0, duration=12.0)\n"
            "m = PerWindow().fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative)\n"
            "m.score(d.X, d.U, groups=d.demo, t=d.t); m.set_fit_request(t=True)\n"
            "print('sklearn' in sys.modules, m._metadata('fit'))\n")
    out = subprocess.run([sys.executable, "-c", code], capture_output=True, text=True, check=True).stdout
    assert out.split()[0] == "False" and "derivative" in out
