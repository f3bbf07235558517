"""Noise estimates from second differences (ccl_cli/learn/noise.py) and the noise-aware rank
rule (ccl_cli/learn/constraint/noise_rank.py), which may answer "no constraint"."""

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.io.derivative import local_polynomial_derivative
from ccl_cli.learn import noise
from ccl_cli.learn.constraint import StateIndependentConstraint
from ccl_cli.learn.constraint import noise_rank as nr


def test_white_noise_variance_per_dimension_and_along_rows():
    rng = np.random.default_rng(0)
    n = 20_000
    t = np.arange(n) * 0.01
    smooth = np.stack([np.sin(t), 0.5 * np.cos(0.7 * t), 0.2 * t], 1)  # Δ² of the motion ~1e-4 × noise
    sigma = np.array([1e-3, 2e-3, 4e-3])
    Y = smooth + rng.normal(size=(n, 3)) * sigma
    demo = np.repeat([0, 1], n // 2)
    est = noise.white_noise_var(Y, demo)
    assert np.allclose(est, sigma**2, rtol=0.05)
    a = np.array([[0.6, 0.8, 0.0], [0.0, 0.0, 2.0]])  # along a: aᵀ diag(σ²) a
    assert np.allclose(noise.white_noise_var(Y, demo, a), (a**2) @ sigma**2, rtol=0.05)
    per_sample = np.broadcast_to(a, (n, 2, 3))
    assert np.allclose(noise.white_noise_var(Y, demo, per_sample), noise.white_noise_var(Y, demo, a))
    _, centre = noise.second_differences(Y, demo)
    assert len(centre) == n - 4 and not np.isin([0, n // 2 - 1, n // 2, n - 1], centre).any()


def test_derived_noise_is_the_variance_of_the_derived_velocity_of_noise():
    rng = np.random.default_rng(1)
    n, dt, sigma = 50_000, 0.02, 1e-3
    t = np.arange(n) * dt
    X = rng.normal(scale=sigma, size=(n, 2))
    demo = np.zeros(n, int)
    U = local_polynomial_derivative(t, X, demo, 9, 2)
    gain = float((noise.slope_filter(dt, 9, 2) ** 2).sum())
    # the slope of a centred quadratic fit is the linear fit's: c_j = j / (dt Σj²)
    j = np.arange(-4, 5)
    assert np.allclose(noise.slope_filter(dt, 9, 2), j / (dt * (j**2).sum()))
    assert np.isclose(U.var(0).mean(), sigma**2 * gain, rtol=0.03)
    assert np.allclose(noise.derived_noise_var(X, demo, dt, 9, 2), sigma**2 * gain, rtol=0.05)


def _nhat_rows(U: np.ndarray) -> np.ndarray:
    return np.linalg.eigh(U.T @ U)[1].T[: U.shape[1] - 1]


def test_evidence_on_a_tracker_plane():
    data = sim.tracker_plane(duration=60.0, noise=1e-3, seed=2)
    rows = _nhat_rows(data.U)
    ev = nr.row_evidence(data.U, rows, data.demo, data.t, data.X, data.derivative)
    assert ev.energy[0] == pytest.approx(np.linalg.eigvalsh(data.U.T @ data.U)[0] / len(data.U))
    # along the normal the actions are the derived noise: energy ≈ its variance
    assert 0.8 < ev.ratio[0] < 1.3
    assert ev.ratio[1] > 20 and ev.share[1] > 0.1
    chosen = nr.noise_rank(ev, 2)
    assert chosen.n_constraints == 1 and chosen.rule == "noise" and "row 2" in chosen.reason


@pytest.mark.parametrize(("make", "truth"), [
    (lambda: sim.free_reach(seed=1), 0),
    (lambda: sim.flow2d(seed=2), 0),
    (lambda: sim.tracker_plane(duration=40.0, noise=2e-3, seed=3), 1),
    (lambda: sim.tracker_sphere(duration=40.0, noise=2e-4, seed=4), 0),  # nhat's one plane misses the bowl
])
def test_derived_velocities(make, truth):
    data = make()
    chosen = nr.choose(data.U, _nhat_rows(data.U), data.demo, data.t, data.n_action - 1, data.X,
                       data.derivative)
    assert chosen.n_constraints == truth
    if truth == 0:
        assert chosen.reason.startswith("no constraint")
        # today's rules always keep row 1
        assert StateIndependentConstraint().fit(data.X, data.U).n_constraints_ == 1


@pytest.mark.parametrize(("rows", "truth"), [((0,), 1), ((0, 1), 2), ((0, 1, 2), 3)])
def test_recorded_actions_of_the_7dof_arm(rows, truth):
    data = sim.arm7(rows=rows, seed=5)
    chosen = nr.choose(data.U, _nhat_rows(data.U), data.demo, data.t, 6)
    assert chosen.n_constraints == truth


def test_a_pressing_contact_is_a_constraint_by_its_share():
    data = sim.arm_wipe(n_demos=3, rate=100.0, seed=6)
    keep = np.zeros(len(data.t), bool)
    for i, p in enumerate(data.metadata["phases"]):
        keep |= (data.demo == i) & (data.t >= p["wipe"][0]) & (data.t < p["wipe"][1])
    wipe = data.subset(keep)
    ev = nr.row_evidence(wipe.U, _nhat_rows(wipe.U), wipe.demo, wipe.t, wipe.X, data.derivative)
    assert ev.ratio[0] > nr.MARGIN  # the tool presses in: motion along n above the sensor's noise ...
    assert ev.share[0] < nr.SHARE / 10  # ... but a negligible share of the motion
    assert nr.noise_rank(ev, 2).n_constraints == 1
    whole = nr.choose(data.U, _nhat_rows(data.U), data.demo, data.t, 2, data.X, data.derivative)
    assert whole.n_constraints == 0  # approach and retract move along n


def test_no_judgement_without_trajectories():
    data = sim.toy2d(sampling="uniform", seed=7)  # states uniform in the box: no time order
    ev = nr.row_evidence(data.U, _nhat_rows(data.U), data.demo, data.t)
    assert ev.snr < nr.MIN_SNR
    assert nr.noise_rank(ev, 1) is None
    trajectories = sim.toy2d(seed=7)
    assert nr.choose(trajectories.U, _nhat_rows(trajectories.U), trajectories.demo, trajectories.t,
                     1).n_constraints == 1


def test_noise_free_constraints_are_kept_by_their_share():
    data = sim.varying_constraint(seed=8).select_demos([3])  # exact: zero motion along the row
    ev = nr.row_evidence(data.U, _nhat_rows(data.U), data.demo, data.t)
    assert ev.share[0] < 1e-20
    assert nr.noise_rank(ev, 1).n_constraints == 1


def test_derived_needs_the_positions():
    data = sim.tracker_plane(duration=10.0, seed=9)
    with pytest.raises(ValueError, match="positions"):
        nr.row_evidence(data.U, _nhat_rows(data.U), data.demo, data.t, None, data.derivative)
