"""Tracker simulations: geometry, sampling, the derivative and the command line."""

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.errors import ConfigError
from ccl_cli.io import load_demonstrations


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt((np.asarray(a) ** 2).sum(-1).mean()))


@pytest.mark.parametrize("problem", ["tracker_plane", "tracker_sphere"])
def test_tracker_shapes_rate_and_truth(problem):
    data = sim.PROBLEMS[problem](duration=60.0, rate=50.0, seed=1)
    assert data.X.shape == data.U.shape == (3000, 3)
    assert data.n_demos == 1  # one continuous recording = one demonstration
    assert np.allclose(np.diff(data.t), 1 / 50.0)
    assert data.state_units == ["m"] * 3 and data.action_units == ["m/s"] * 3
    A = data.truth_per_sample("A")
    assert A.shape == (3000, 1, 3)
    assert np.allclose(np.linalg.norm(A, axis=-1), 1.0)
    pi = data.truth["pi"]
    # the intended motion is tangential: A π = 0 and π = w = Nπ
    assert np.abs(np.einsum("nsq,nq->ns", A, pi)).max() < 1e-12
    assert np.allclose(np.einsum("nij,nj->ni", data.true_projection(), pi), pi)
    assert np.array_equal(data.truth["w"], pi) and not data.truth["v"].any()
    # static stretches and a wide range of speeds (m/s)
    speed = np.linalg.norm(pi, axis=1)
    assert 0.05 < (speed == 0).mean() < 0.4
    assert 0.1 < speed.max() < 0.6 and 0.01 < np.median(speed) < 0.1
    if problem == "tracker_plane":
        assert data.truth["A"].shape == (1, 3)  # stored once: state-independent


def test_noise_free_geometry():
    plane = sim.tracker_plane(duration=30.0, noise=0.0, seed=2)
    n = plane.truth["A"][0]
    heights = plane.X @ n
    assert np.ptp(heights) < 1e-12  # every position on the plane
    assert _rms(plane.U @ n) < 1e-12 * _rms(plane.U)  # derived velocities in the plane
    bowl = sim.tracker_sphere(duration=30.0, noise=0.0, radius=0.25, seed=2)
    d = bowl.truth["A"][:, 0, :]
    centre = bowl.X - 0.25 * d  # x = c + R d(x): the same centre for every sample
    assert np.ptp(centre, axis=0).max() < 1e-12
    # the derivative of a curved path bends inwards by O(h²): small, not zero
    ratio = _rms(np.einsum("nq,nq->n", d, bowl.U)[:, None]) / _rms(bowl.U)
    assert 1e-4 < ratio < 1e-2


@pytest.mark.parametrize(("rate", "window", "bound"), [(50.0, None, 0.06), (500.0, None, 0.06),
                                                      (500.0, 9, 1e-3)])
def test_derivative_error_at_zero_noise(rate, window, bound):
    # the error of a degree-2 fit grows with the window's time span (0.16 s by default)
    data = sim.tracker_plane(duration=30.0, rate=rate, window=window, noise=0.0, seed=3)
    err = _rms(data.U - data.truth["pi"]) / _rms(data.truth["pi"])
    assert err < bound


def test_position_noise_reaches_the_derived_velocity_as_the_reader_derivative_predicts():
    # window 9, degree 2, uniform 50 Hz: the slope's noise std is σ / (Δt √Σk²), Σk² = 60
    data = sim.tracker_plane(duration=120.0, noise=1e-3, window=9, seed=4)
    normal_u = data.U @ data.truth["A"][0]
    interior = np.ones(len(data.U), bool)
    interior[:4] = interior[-4:] = False  # the shifted windows at the ends differ
    expected = 1e-3 / (0.02 * np.sqrt(60.0))
    assert abs(normal_u[interior].std() / expected - 1.0) < 0.05
    pos_noise = (data.X - data.X.mean(0)) @ data.truth["A"][0]
    assert abs(pos_noise.std() / 1e-3 - 1.0) < 0.05


def test_default_window_spans_the_same_time_at_any_rate():
    slow = sim.tracker_plane(duration=10.0, rate=50.0, noise=0.0)
    fast = sim.tracker_plane(duration=10.0, rate=500.0, noise=0.0)
    assert slow.derivative.window == 9
    assert fast.derivative.window == 81


def test_recordings_jitter_drift_and_seeds():
    data = sim.tracker_sphere(duration=20.0, n_recordings=3, seed=5)
    assert data.n_demos == 3 and len(data.X) == 3000
    assert np.allclose(data.t[data.demo == 2][:3], [0.0, 0.02, 0.04])
    again = sim.tracker_sphere(duration=20.0, n_recordings=3, seed=5)
    assert np.array_equal(data.X, again.X) and np.array_equal(data.U, again.U)
    other = sim.tracker_sphere(duration=20.0, n_recordings=3, seed=6)
    assert not np.allclose(data.X, other.X)
    jittery = sim.tracker_plane(duration=20.0, jitter=2e-3, seed=5)
    steps = np.diff(jittery.t)
    assert (steps > 0).all() and 0.5 * 2e-3 < steps.std() < 2 * np.sqrt(2) * 2e-3
    drifting = sim.tracker_plane(duration=60.0, noise=0.0, drift=1e-4, seed=5)
    still = sim.tracker_plane(duration=60.0, noise=0.0, seed=5)
    assert np.allclose(np.linalg.norm(drifting.X[-1] - still.X[-1]), 1e-4 * 59.98)
    with pytest.raises(ConfigError):
        sim.tracker_plane(duration=0.1, rate=50.0)


def test_simulate_command_writes_a_tracker_recording(tmp_path):
    out = tmp_path / "bowl.h5"
    code = main(["simulate", "tracker_sphere", "-o", str(out), "--rate", "100", "--duration", "12",
                 "--noise", "0.0005", "--n-recordings", "2", "--seed", "7", "-q"])
    assert code == 0
    data = load_demonstrations({"files": [str(out)]})
    direct = sim.tracker_sphere(rate=100.0, duration=12.0, noise=5e-4, n_recordings=2, seed=7)
    assert data.n_demos == 2 and len(data.X) == 2400
    assert np.allclose(data.X, direct.X) and np.allclose(data.U, direct.U)
    assert np.allclose(data.truth_per_sample("A"), direct.truth_per_sample("A"))
    assert main(["simulate", "toy2d", "-o", str(tmp_path / "t.h5"), "--rate", "50", "-q"]) == 2


def test_spread_and_wobble():
    even = sim.tracker_plane(duration=60.0, noise=0.0, seed=8)
    squashed = sim.tracker_plane(duration=60.0, noise=0.0, spread=0.2, seed=8)
    ev_even = np.linalg.eigvalsh(np.cov(even.U.T))
    ev_sq = np.linalg.eigvalsh(np.cov(squashed.U.T))
    assert ev_even[1] / ev_even[2] > 0.3
    assert abs(ev_sq[1] / ev_even[1] - 0.04) < 0.03  # in-plane variance across scales by spread²
    rocking = sim.tracker_plane(duration=60.0, noise=0.0, wobble=1e-3, seed=8)
    off = rocking.X @ rocking.truth["A"][0]
    assert abs(off.std() / 1e-3 - 1.0) < 0.35  # a slow signal: few cycles in 60 s
    assert np.allclose(rocking.truth["pi"], even.truth["pi"])  # the intention is unchanged


def test_two_link_task_part_lies_in_the_constrained_space():
    """u = A⁺b + Nπ: A u reproduces each demonstration's b, N u is the null-space part w,
    and without ``task`` the seeds give the same arm as before (v = 0)."""
    d = sim.two_link(task=True, seed=3, n_demos=6, n_steps=15)
    t = d.truth
    b = np.einsum("nsq,nq->ns", t["A"], d.U)
    np.testing.assert_allclose(b, t["b"], atol=1e-12)
    assert np.ptp(t["b"]) > 0.1 and np.all(np.abs(t["b"]) <= 1.0)
    assert np.allclose([np.ptp(t["b"][d.demo == k]) for k in range(6)], 0.0)
    np.testing.assert_allclose(np.einsum("nij,nj->ni", t["N"], d.U), t["w"], atol=1e-12)
    np.testing.assert_allclose(t["v"] + t["w"], d.U, atol=1e-12)
    plain = sim.two_link(seed=3, n_demos=6, n_steps=15)
    assert np.allclose(plain.truth["v"], 0.0) and plain.X.shape == d.X.shape
    np.testing.assert_allclose(plain.X[d.demo == 0][0], d.X[d.demo == 0][0])


def test_limit_cycle_trajectories_end_before_they_overflow():
    """The §7 limit cycle repels: starts outside r spiral out. Trajectories end when they
    leave the escape box, so every sample is finite (it overflowed to inf before)."""
    for seed in range(3):
        d = sim.toy2d(policy="limit_cycle", seed=seed)
        assert np.isfinite(d.U).all() and np.isfinite(d.X).all()
        assert np.abs(d.X).max() <= sim.reference.ESCAPE
        assert 300 < len(d.X) < 1000  # some trajectories escape, most run on


@pytest.mark.parametrize(("window", "order", "chunk"),
                         [(9, 2, 8192), (101, 2, 1000), (7, 3, 333), (3, 1, 50)])
def test_the_local_polynomial_derivative_of_a_polynomial_is_exact_everywhere(window, order, chunk):
    """A polynomial of the fit's degree on jittered stamps: its derivative at every sample —
    centred windows, windows shifted at a demonstration's ends, demonstrations shorter than
    the window, chunk edges."""
    from ccl_cli.io.derivative import local_polynomial_derivative

    rng = np.random.default_rng(window)
    sizes = [3000, 40, order + 1, 2000]
    demo = np.repeat(np.arange(len(sizes)), sizes)
    t = np.cumsum(rng.uniform(0.8e-3, 1.2e-3, len(demo)))
    tc = t - 2.5  # centred: the coefficients stay of order one
    coef = rng.normal(size=(order + 1, 2))
    Y = sum(coef[k] * tc[:, None] ** k for k in range(order + 1))
    dY = sum(k * coef[k] * tc[:, None] ** (k - 1) for k in range(1, order + 1))
    U = local_polynomial_derivative(t, Y, demo, window, order, chunk)
    np.testing.assert_allclose(U, dY, rtol=0, atol=1e-6 * np.abs(dY).max())
