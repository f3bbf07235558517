"""The constraint-model protocol (issue 27): every constraint learner — learn-a's ``auto``
included — answers the same questions with the same signatures, and the app, the model files
and the renderers ask nothing else. Each learner is fitted on simulated data with ground truth
and its answers are checked against the truth; its rule for a recording it has not seen is
applied and checked the same way. Seeds are fixed."""

import ast
from pathlib import Path

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.errors import InputError
from ccl_cli.learn import constraint as C
from ccl_cli.learn.linalg import nullspace_projection
from ccl_cli.models import load_model, save_model

ROOT = Path(__file__).resolve().parents[1] / "ccl_cli"


def median_error(model, d) -> float:
    """Median over the samples of max |Ñ − N_true| (the model's projection against the truth)."""
    N = model.projection(d.X, groups=d.demo, t=d.t)
    return float(np.median(np.abs(N - d.true_projection()).max((1, 2))))


def split(d, data):
    """The first two thirds of the demonstrations to fit on, the rest as a recording the model has
    not seen (one demonstration: another recording of the same simulator)."""
    ids = d.demo_ids
    if len(ids) < 2:
        return d, data(2)
    cut = ids[: (2 * len(ids)) // 3]
    return d.select_demos(cut), d.select_demos([i for i in ids if i not in cut])


#: name, learner, data (by seed), k, local_to, varies_with_state, the rule for new data, what
#: answers (auto: the class it chooses), median |Ñ − N_true| bounds on the fitted and the new data
CASES = [
    ("nhat", C.StateIndependentConstraint, lambda s: sim.tracker_plane(duration=15.0, n_recordings=3, seed=s),
     1, None, False, "as fitted", "StateIndependentConstraint", 0.01, 0.01),
    ("alpha", lambda: C.StateDependentConstraint(tune=False),
     lambda s: sim.toy2d(constraint="parabola", seed=s, n_demos=24),
     1, None, True, "as fitted", "StateDependentConstraint", 0.04, 0.12),
    ("lambda", lambda: C.KnownFeatureConstraint(features="arm2", tune=False, n_restarts=1),
     lambda s: sim.two_link(seed=s, n_demos=12, n_steps=20),
     1, None, True, "as fitted", "KnownFeatureConstraint", 1e-4, 1e-3),
    ("linear", lambda: C.LinearConstraint(regressors="polynomial", degree=1, tune=False),
     lambda s: sim.toy2d(constraint="parabola", seed=s, n_demos=12),
     1, None, True, "as fitted", "LinearConstraint", 0.04, 0.05),
    ("none", C.NoConstraint, lambda s: sim.free_reach(n_demos=3, seed=s), 0, None, False, "as fitted",
     "NoConstraint", 0.0, 0.0),
    ("per_demo", lambda: C.PerDemonstration(C.StateIndependentConstraint(n_constraints=1)),
     lambda s: sim.varying_constraint(seed=s), 1, "demonstration", False, "fitted per demonstration",
     "PerDemonstration", 1e-12, 1e-12),
    ("per_window", lambda: C.PerWindow(window=6.0), lambda s: sim.tracker_tilt(seed=s, duration=36.0),
     1, "window", False, "rows fitted per stretch", "PerWindow", 0.08, 0.08),
    ("per_segment", C.PerSegment, lambda s: sim.tracker_tilt(mode="steps", seed=s, duration=36.0),
     1, "segment", False, "rows fitted per stretch", "PerSegment", 0.04, 0.04),
    ("stretches", C.ConstraintInStretches, lambda s: sim.arm_wipe(n_demos=4, seed=s),
     1, "stretch", True, "stretches classified", "ConstraintInStretches", 1e-3, 1e-3),
    ("manifold", lambda: C.ManifoldConstraint(family="sphere", n_constraints=1),
     lambda s: sim.tracker_sphere(duration=15.0, n_recordings=3, seed=s),
     1, None, True, "as fitted", "ManifoldConstraint", 0.02, 0.02),
    ("auto", C.AutoConstraint, lambda s: sim.arm7(rows=(0, 1), seed=s, n_demos=12),
     2, None, False, "as fitted", "StateIndependentConstraint", 0.01, 0.01),
]
IDS = [c[0] for c in CASES]


@pytest.fixture(scope="module")
def fitted():
    """Each learner fitted, through the one signature, on the first two thirds of its data."""
    out = {}
    for name, make, data, *_ in CASES:
        train, new = split(data(1), data)
        model = make().fit(train.X, train.U, groups=train.demo, t=train.t, derivative=train.derivative)
        out[name] = (model, train, new)
    return out


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_every_constraint_learner_answers_the_protocol(case, fitted, tmp_path):
    name, _, _, k, local_to, varies, rule, answers, bound, _ = case
    model, d, _ = fitted[name]
    at = {"groups": d.demo, "t": d.t}
    assert model.n_constraints_ == k and model.n_action_ == d.n_action
    assert model.local_to == local_to and model.is_local == (local_to is not None)
    assert model.varies_with_state is varies
    assert type(model.chosen_).__name__ == answers and model.selection_["reason"]
    assert model.new_data_rule.rule == rule and model.new_data_rule.words
    assert median_error(model, d) <= bound
    # the rows and the projection agree: Ñ = I − Ã⁺Ã at every sample
    A = model.constraint(d.X, **at)
    assert A.shape == (d.n_samples, k, d.n_action)
    np.testing.assert_allclose(nullspace_projection(A), model.projection(d.X, **at), atol=1e-8)
    # where the model claims its rows: everywhere, but for the constraint in stretches (the wipes)
    holds = model.holds(d.X, **at)
    wiping = np.abs(d.true_projection() - np.eye(d.n_action)).max((1, 2)) > 0
    if name == "stretches":
        assert 0.5 < holds.mean() < 0.95 and (holds == wiping).mean() > 0.95
    else:
        assert holds.all()
    assert 0.0 <= model.held_out_error(d.X, d.U, **at) <= 0.05
    # score: the split's likelihood gain by hand — 0 without rows, positive with quiet rows
    N, U = model.projection(d.X, **at), d.U
    free = np.einsum("nij,nj->ni", N, U)
    Ef, Ec = (free**2).sum(1).mean(), ((U - free) ** 2).sum(1).mean()
    q, r = d.n_action, np.trace(np.eye(d.n_action) - N, axis1=1, axis2=2).mean()  # r: the mean rank
    by_hand = 0.0 if k == 0 else 0.5 * (q * np.log((Ec + Ef) / q) - r * np.log(max(Ec, 1e-12 * (Ec + Ef)) / r)
                                         - (q - r) * np.log(Ef / (q - r))) / q
    assert model.score(d.X, d.U, **at) == pytest.approx(by_hand, rel=1e-9, abs=1e-12)
    assert (by_hand > 0.1) == (k > 0)
    # a model file holds what answers; its own checks pass, and it predicts the same
    model.chosen_.check_shapes()
    back, _ = load_model(save_model(tmp_path / "m.h5", model))
    assert type(back).__name__ == answers and back.new_data_rule == model.new_data_rule
    np.testing.assert_array_equal(back.projection(d.X, **at), model.projection(d.X, **at))


@pytest.mark.parametrize("case", CASES, ids=IDS)
def test_a_recording_it_has_not_seen_gets_the_stated_rule(case, fitted):
    name, *_, rule, _, _, bound = case
    model, d, new = fitted[name]
    stated = model.new_data_rule
    once = model.applies_to(new.X, new.U, groups=new.demo, t=new.t)
    again = model.applies_to(new.X, new.U, groups=new.demo, t=new.t)
    assert once.rule == stated and once.note == again.note  # deterministic, and said
    N = once.model.projection(new.X, groups=new.demo, t=new.t)
    np.testing.assert_array_equal(N, again.model.projection(new.X, groups=new.demo, t=new.t))
    assert median_error(once.model, new) <= bound
    assert once.refitted == (rule != "as fitted")
    if once.refitted:
        assert once.model is not model and once.note
        assert once.model.n_constraints_ == model.n_constraints_ or not stated.carries_over
    else:
        assert once.model is model.chosen_ and once.note is None
    assert stated.carries_over == (name != "per_demo")
    # on the recordings it was fitted on (a held-out part of them), a model applies as fitted
    own = model.applies_to(d.X, d.U, groups=d.demo, t=d.t, new_recording=False)
    assert own.model is model.chosen_ and own.note is None


def test_a_per_demonstration_model_pads_the_rows_of_fewer_constraints():
    """Ã of a demonstration whose model has fewer rows is padded with rows of zeros: Ñ unchanged."""
    d = sim.varying_constraint(seed=0)
    ids = d.demo_ids[:2]
    d = d.select_demos(ids)
    model = C.PerDemonstration(C.StateIndependentConstraint(n_constraints=1)).fit(d.X, d.U, groups=d.demo)
    model.models_[int(ids[1])] = C.NoConstraint().fit(d.X[d.demo == ids[1]], d.U[d.demo == ids[1]])
    A = model.constraint(d.X, groups=d.demo)
    assert A.shape == (d.n_samples, 1, d.n_action)
    assert not A[d.demo == ids[1]].any() and np.abs(A[d.demo == ids[0]]).sum() > 0
    np.testing.assert_allclose(nullspace_projection(A), model.projection(d.X, groups=d.demo), atol=1e-12)
    with pytest.raises(InputError, match="not seen"):
        model.constraint(d.X, groups=d.demo + 10)


def test_a_damaged_array_is_named_by_the_learner_itself():
    d = sim.tracker_plane(duration=10.0, seed=0)
    model = C.StateIndependentConstraint().fit(d.X, d.U)
    model.A_ = np.zeros((2, 3))  # two rows where one was learnt
    with pytest.raises(InputError, match="array A_ has the wrong shape for a StateIndependentConstraint"):
        model.check_shapes()


def _learner_names() -> set[str]:
    names = set(C.__all__)
    names |= {"NullSpaceComponent", "PolicyLearner", "Tuned", "TimedConstraint"}
    return names


@pytest.mark.parametrize("path", sorted([*(ROOT / "app").glob("*.py"), *(ROOT / "render").glob("*.py"),
                                         ROOT / "models.py"]), ids=lambda p: f"{p.parent.name}/{p.name}")
def test_the_app_asks_through_the_protocol(path):
    """No isinstance on a learner class and no reaching into auto's ``model_`` outside learn/."""
    tree = ast.parse(path.read_text())
    learners = _learner_names()
    for node in ast.walk(tree):
        if isinstance(node, ast.Call) and getattr(node.func, "id", None) == "isinstance":
            named = {n.id for n in ast.walk(node.args[1]) if isinstance(n, ast.Name)}
            named |= {n.attr for n in ast.walk(node.args[1]) if isinstance(n, ast.Attribute)}
            assert not named & learners, f"{path.name}:{node.lineno} isinstance on {named & learners}"
        if isinstance(node, ast.Attribute):
            assert node.attr not in ("model_", "needs_time", "needs_demo"), f"{path.name}:{node.lineno}"
        if isinstance(node, ast.Constant) and node.value in ("model_", "needs_time", "needs_demo"):
            raise AssertionError(f"{path.name}:{node.lineno} asks for {node.value!r}")
