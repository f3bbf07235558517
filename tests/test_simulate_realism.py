"""What real logs add to a simulated motion (ccl_cli/simulate/realism.py, mechanisms.py,
contact.py, free.py): each effect as documented — its size, band and direction — the ground
truth exact on the noise-free motion, the paths of the documented shape, and ``ccl simulate``
writing them with ``--set``."""

from __future__ import annotations

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import load_demonstrations
from ccl_cli.simulate.contact import phase_of
from ccl_cli.simulate.realism import TREMOR_HZ

#: Every effect off: the ideal motion.
IDEAL = {"noise": 0.0, "compliance": 0.0, "tremor": 0.0, "drift": 0.0}


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt(np.mean(np.asarray(a) ** 2)))


def _velocity(d) -> np.ndarray:
    return d.truth["w"] + d.truth["v"]


def test_hinge_ideal_motion_is_on_each_trials_circle():
    d = sim.hinge(seed=3, **IDEAL)
    A, xdot = d.truth["A"], _velocity(d)
    assert A.shape == (d.n_samples, 2, 3)
    np.testing.assert_allclose(np.einsum("nki,nki->n", A, A), 2.0)  # two unit rows
    assert np.abs(np.einsum("nkq,nq->nk", A, xdot)).max() < 1e-6  # the rows do not move: b = 0
    axis = np.asarray(d.metadata["axis"])
    radii, sweeps = [], []
    for i, info in enumerate(d.metadata["demos"]):
        P = d.X[d.demo == i] - np.asarray(info["centre"])
        along = P @ axis
        radial = P - np.outer(along, axis)
        np.testing.assert_allclose(np.linalg.norm(radial, axis=1), info["radius_m"], atol=1e-9)
        np.testing.assert_allclose(along, info["height_m"], atol=1e-9)
        cosang = radial[0] @ radial[-1] / info["radius_m"] ** 2
        sweeps.append(np.degrees(np.arccos(np.clip(cosang, -1, 1))))
        radii.append(info["radius_m"])
        assert np.isclose(sweeps[-1], info["sweep_deg"], atol=1e-6)
    assert 60 <= min(sweeps) and max(sweeps) <= 120
    door = d.metadata["door_radius_m"]
    assert 0.3 <= door <= 0.67 and np.abs(np.array(radii) - door).max() <= 0.03
    centres = np.array([info["centre"] for info in d.metadata["demos"]])
    assert np.abs(centres - centres.mean(0)).max() <= 0.1 + 1e-12  # each trial's frame: a translation
    # rests at both ends, 1–2 mm a step in between at 30 Hz
    steps = np.linalg.norm(np.diff(d.X, axis=0), axis=1)[d.demo[1:] == d.demo[:-1]]
    assert steps.min() < 1e-6 and 1e-3 < np.median(steps[steps > 1e-4]) < 2.5e-3


def test_compliance_is_low_pass_motion_along_the_rows():
    """The effect alone (its own random stream: the same path without it) moves the hand only
    along the rows, by ~``compliance`` RMS, correlated over many samples (unlike white noise)."""
    base = sim.hinge(seed=5, **IDEAL)
    giving = sim.hinge(seed=5, **{**IDEAL, "compliance": 2e-3})
    D = giving.X - base.X
    A = base.truth["A"]
    along = np.einsum("nkq,nq->nk", A, D)
    assert _rms(D - np.einsum("nkq,nk->nq", A, along)) < 1e-3 * _rms(along)  # only along the rows
    assert 1.2e-3 < _rms(along) < 3e-3
    for i in base.demo_ids:  # low-pass: the second differences are tiny against the motion itself
        r = along[base.demo == i, 1]
        assert np.std(np.diff(r, 2)) / np.sqrt(6) < 0.05 * np.std(r)
    assert np.abs(np.einsum("nkq,nq->nk", A, _velocity(giving))).max() > 1e-3  # b ≠ 0: the true motion
    np.testing.assert_allclose(giving.truth["b"], np.einsum("nkq,nq->nk", A, _velocity(giving)), atol=1e-12)


def test_tremor_is_in_its_band_and_in_every_direction():
    base = sim.contact_phases(n_demos=2, seed=2, **IDEAL)
    shaky = sim.contact_phases(n_demos=2, seed=2, **{**IDEAL, "tremor": 5e-4})
    D = shaky.X - base.X
    assert np.allclose(np.sqrt((D**2).mean(0)), 5e-4, rtol=0.35)  # each axis
    f = np.fft.rfftfreq(len(D), 1 / 100.0)
    power = (np.abs(np.fft.rfft(D[shaky.demo == 0], n=len(D), axis=0)) ** 2).sum(1)
    inside = (f >= TREMOR_HZ[0] - 0.5) & (f <= TREMOR_HZ[1] + 0.5)
    assert power[inside].sum() > 0.95 * power.sum()


def test_drift_walks_off_at_its_rate():
    base = sim.slide(seed=1, **IDEAL)
    off = sim.slide(seed=1, **{**IDEAL, "drift": 2e-4})
    for i in base.demo_ids:
        m = base.demo == i
        D = off.X[m] - base.X[m]
        slope = np.linalg.lstsq(np.c_[base.t[m], np.ones(m.sum())], D, rcond=None)[0][0]
        assert np.isclose(np.linalg.norm(slope), 2e-4, rtol=1e-9)
    np.testing.assert_array_equal(off.truth["A"], base.truth["A"])  # the sensor's, not the motion's


def test_filtered_velocities_are_recorded_and_lag():
    d = sim.slide(seed=2, velocities="filtered", filter_hz=2.0, **IDEAL)
    derived = sim.slide(seed=2, **IDEAL)
    assert d.derivative.derived is False and derived.derivative.derived is True
    np.testing.assert_array_equal(d.X, derived.X)
    xdot = _velocity(d)
    m = d.demo == 0
    u, v = d.U[m] @ np.asarray(d.metadata["direction"]), xdot[m] @ np.asarray(d.metadata["direction"])
    lags = np.arange(0, 8)
    err = [np.mean((u[k:] - v[: len(v) - k]) ** 2) for k in lags]
    assert lags[int(np.argmin(err))] == round(30.0 / (2 * np.pi * 2.0))  # the filter's lag, 1/(2πf) s
    assert _rms(derived.U[m] - xdot[m]) < 0.2 * _rms(d.U[m] - xdot[m])


def test_slide_bows_within_its_bound_and_the_rows_follow_the_rail():
    d = sim.slide(seed=4, bow=0.02, **IDEAL)
    e = np.asarray(d.metadata["direction"])
    A, xdot = d.truth["A"], _velocity(d)
    assert np.abs(np.einsum("nkq,nq->nk", A, xdot)).max() < 1e-6
    tilt = np.degrees(np.arcsin(np.linalg.norm(A @ e, axis=1)))  # the rows' angle off e's complement
    for i, info in enumerate(d.metadata["demos"]):
        P = d.X[d.demo == i] - np.asarray(info["origin"])
        off_line = P - np.outer(P @ e, e)
        # the largest deviation, sampled near the middle of the travel
        assert np.isclose(np.linalg.norm(off_line, axis=1).max(), abs(info["bow_m"]), rtol=1e-3)
        bound = np.degrees(np.arctan(np.pi * abs(info["bow_m"]) / info["travel_m"]))
        assert tilt[d.demo == i].max() <= bound + 1e-6 and tilt[d.demo == i].max() > 0.9 * bound
        assert 0.4 <= info["travel_m"] <= 0.5


@pytest.mark.parametrize("surface", ["plane", "sphere"])
def test_contact_phases(surface):
    d = sim.contact_phases(surface=surface, seed=1, **{**IDEAL, "compliance": 1.5e-3})
    phase = phase_of(d)
    share = d.metadata["contact_share"]
    assert 0.7 <= share <= 0.85 and np.isclose((phase == 1).mean(), share)
    N = d.truth["N"]
    np.testing.assert_allclose(N[phase != 1], np.broadcast_to(np.eye(3), (int((phase != 1).sum()), 3, 3)))
    assert np.allclose(np.trace(N[phase == 1], axis1=1, axis2=2), 2.0)
    n = np.asarray(d.metadata["normal"])
    centre = np.asarray(d.metadata["centre"])
    if surface == "plane":  # the height over the table: the pad's give in contact, 10–20 cm at the start
        height = (d.X - centre) @ n
    else:  # the bowl: the distance inside its sphere
        middle = centre + 0.25 * n
        height = 0.25 - np.linalg.norm(d.X - middle, axis=1)
    assert 0.7e-3 < _rms(height[phase == 1]) < 2.5e-3
    starts = np.flatnonzero(np.r_[True, d.demo[1:] != d.demo[:-1]])
    assert np.all((height[starts] >= 0.1 - 1e-9) & (height[starts] <= 0.2 + 1e-9))
    v = d.truth["v"]
    assert not v[phase != 1].any() and _rms(v[phase == 1]) > 1e-3  # the pressing motion along n


def test_free_motion_truth_and_shape():
    reach = sim.reach_goal(seed=1)
    assert np.array_equal(reach.truth["N"], np.eye(3)) and not reach.truth["v"].any()
    ends = np.flatnonzero(np.r_[reach.demo[1:] != reach.demo[:-1], True])
    goal = np.asarray(reach.metadata["goal"])
    assert np.abs(reach.X[ends] - goal).max() < 3e-3  # every reach ends on the goal (noise, tremor)
    smallest = []
    for i in reach.demo_ids:
        V = reach.truth["pi"][reach.demo == i]
        ev = np.sqrt(np.linalg.eigvalsh(V.T @ V / len(V)))
        smallest.append(ev[0] / ev[2])
    assert 0.1 < min(smallest) and max(smallest) < 0.45  # nearly planar reaches, never flat
    writing = sim.handwriting(seed=2)
    assert writing.X.shape[1] == 2 and writing.n_demos == 4
    ev = np.linalg.eigvalsh(writing.truth["pi"].T @ writing.truth["pi"])
    assert ev[0] / ev[1] > 0.3  # the pen moves in both directions


def test_a_rate_samples_the_same_motion():
    """The effects are functions of time: sampled at 60 Hz, the motion passes through the 30-Hz samples."""
    slow = sim.hinge(seed=6, rate=30.0, **{**IDEAL, "compliance": 2e-3, "tremor": 3e-4})
    fast = sim.hinge(seed=6, rate=60.0, **{**IDEAL, "compliance": 2e-3, "tremor": 3e-4})
    for i in slow.demo_ids:
        a, b = slow.X[slow.demo == i], fast.X[fast.demo == i][::2]
        n = min(len(a), len(b)) - 1
        np.testing.assert_allclose(a[:n], b[:n], atol=1e-12)


def test_bad_settings_are_one_line_errors():
    from ccl_cli.errors import ConfigError

    with pytest.raises(ConfigError, match="sweep_deg must be"):
        sim.hinge(sweep_deg=(90.0, 60.0))
    with pytest.raises(ConfigError, match="velocities must be one of derived, filtered"):
        sim.slide(velocities="smooth")
    with pytest.raises(ConfigError, match="surface must be one of plane, sphere"):
        sim.contact_phases(surface="cube")


@pytest.mark.parametrize(("problem", "settings", "kwargs"), [
    ("hinge", ["--set", "compliance=0.003", "--set", "sweep_deg=[70, 80]"],
     {"compliance": 0.003, "sweep_deg": (70, 80)}),
    ("slide", ["--set", "velocities=filtered", "--set", "bow=0.01"], {"velocities": "filtered", "bow": 0.01}),
    ("contact_phases", ["--n-demos", "2", "--set", "surface=sphere"], {"n_demos": 2, "surface": "sphere"}),
    ("reach_goal", ["--n-demos", "3"], {"n_demos": 3}),
    ("handwriting", ["--set", "n_words=2"], {"n_words": 2}),
])
def test_simulate_command_writes_them(tmp_path, problem, settings, kwargs):
    out = tmp_path / f"{problem}.h5"
    assert main(["simulate", problem, "-o", str(out), "--seed", "2", "-q", *settings]) == 0
    keep = {"flips": "keep", "spikes": "keep", "stamps": "keep"}
    data = load_demonstrations({"files": [str(out)], "faults": keep})
    direct = sim.PROBLEMS[problem](seed=2, **kwargs)
    np.testing.assert_allclose(data.X, direct.X)
    np.testing.assert_allclose(data.U, direct.U)
    np.testing.assert_allclose(data.true_projection(), direct.true_projection(), atol=1e-12)
    if "A" in direct.truth:
        np.testing.assert_allclose(data.truth_per_sample("A"), direct.truth["A"])
    # derived velocities say so in the file; recorded (filtered) ones are not said derived
    assert (data.derivative.derived is True) == (kwargs.get("velocities", "derived") == "derived")


@pytest.mark.parametrize(("args", "message"), [
    (["--set", "compliance"], "--set takes NAME=VALUE"),
    (["--set", "bogus=1"], "hinge takes no --bogus"),
    (["--set", "rate=20", "--rate", "30"], "--set rate repeats an option of its own"),
    (["--set", "radius={a: 1}"], "is not a number, a word or a list of numbers"),
])
def test_simulate_set_errors(tmp_path, capsys, args, message):
    assert main(["simulate", "hinge", "-o", str(tmp_path / "h.h5"), *args]) == 2
    err = capsys.readouterr().err.strip()
    assert message in err and len(err.splitlines()) == 1
