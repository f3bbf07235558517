"""Realistic recordings (ccl_cli/simulate/recordings.py, wipe.py): their ground truth holds on
the simulated motion, the faults sit where the metadata says, and ``ccl simulate`` writes them."""

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import load_demonstrations
from ccl_cli.learn.kinematics import SevenDofArm
from ccl_cli.simulate.wipe import WIPE


def _rms(a: np.ndarray) -> float:
    return float(np.sqrt((np.asarray(a) ** 2).sum(-1).mean()))


def test_flips_mirror_the_clean_recording_through_the_transmitter():
    clean = sim.tracker_plane(duration=60.0, seed=3)
    data = sim.tracker_flips(duration=60.0, n_flips=3, seed=3)
    flips = data.metadata["faults"][0]
    assert flips["kind"] == "hemisphere_flip" and flips["count"] == 3
    mirrored = np.zeros(len(data.t), bool)
    for (a, b), (t0, t1) in zip(flips["ranges"], flips["times"], strict=True):
        assert 15 <= b - a <= 20 and np.isclose(t1 - t0, (b - a - 1) / 50.0)  # 0.3–0.4 s at 50 Hz
        mirrored[a:b] = True
    assert np.array_equal(data.X[mirrored], -clean.X[mirrored])
    assert np.array_equal(data.X[~mirrored], clean.X[~mirrored])
    assert np.array_equal(data.truth["A"], clean.truth["A"]) and np.array_equal(data.t, clean.t)
    # the derived velocity jumps by metres per second at the flips, and is the clean one far from them
    assert min(flips["peak_speed"]) > 2.0
    far = np.ones(len(data.t), bool)
    for a, b in flips["ranges"]:
        far[a - 10:b + 10] = False
    assert np.allclose(data.U[far], clean.U[far])


def test_stamp_faults_and_spikes_as_described():
    kinds = ("duplicate", "skip", "step", "back", "repeat")
    data = sim.tracker_flips(n_flips=0, n_spikes=2, stamp_faults=kinds, duration=40.0, seed=1)
    clean = sim.tracker_plane(duration=40.0, seed=1)
    assert len(data.t) == len(clean.t)  # one sample duplicated, one lost
    faults = {f["kind"]: f for f in data.metadata["faults"]}
    dt = np.diff(data.t)
    (i,), (j,), (k,), (m,), (g,) = (faults[kind]["ranges"][0][:1] for kind in (
        "duplicate_sample", "bad_stamp", "backward_stamp", "clock_step", "gap"))
    assert data.t[i] == data.t[i - 1] and np.array_equal(data.X[i], data.X[i - 1])
    assert data.t[j] == data.t[j - 1] and not np.array_equal(data.X[j], data.X[j - 1])
    assert -5 * 0.02 <= dt[k - 1] <= -0.02 + 1e-9
    assert 0.2 <= dt[m - 1] - 0.02 <= 1.0
    assert np.isclose(dt[g - 1], 0.04)
    for a, _ in faults["spike"]["ranges"]:
        jump = np.linalg.norm(data.X[a] - 0.5 * (data.X[a - 1] + data.X[a + 1]))
        assert 0.015 < jump < 0.09


def test_tilting_board():
    for mode in ("smooth", "steps"):
        data = sim.tracker_tilt(mode=mode, noise=0.0, seed=2)
        A = data.truth["A"][:, 0, :]
        xdot = data.truth["w"] + data.truth["v"]
        # the true velocity is the path's derivative; its normal part is b (the board turns)
        assert _rms(np.gradient(data.X, data.t, axis=0)[5:-5] - xdot[5:-5]) < 0.02 * _rms(xdot)
        assert np.allclose(np.einsum("nq,nq->n", A, xdot), data.truth["b"][:, 0])
        assert np.abs(np.einsum("nq,nq->n", A, data.truth["w"])).max() < 1e-12
        lo, hi = data.metadata["angle_range_deg"]
        assert 0 <= lo < 10 and 10 < hi <= 28
        assert len(data.metadata["windows"]) == 10
        # the board turns slowly (steps: in 0.5 s): the motion along its normal is a small part
        assert _rms(data.truth["b"]) < (0.05 if mode == "smooth" else 0.15) * _rms(data.truth["w"])


def _phase(data) -> np.ndarray:
    phase = np.zeros(len(data.t), int)
    for i, p in enumerate(data.metadata["phases"]):
        for code, name in enumerate(("approach", "wipe", "retract")):
            t0, t1 = p[name]
            phase[(data.demo == i) & (data.t >= t0) & (data.t < t1)] = code
    return phase


def test_arm_wipe_task_space():
    data = sim.arm_wipe(n_demos=3, rate=100.0, seed=4)
    n = np.asarray(data.metadata["normal"])
    wiping = _phase(data) == WIPE
    assert 0.6 < wiping.mean() < 0.95
    N = data.true_projection()
    assert np.allclose(N[wiping], np.eye(3) - np.outer(n, n)) and np.allclose(N[~wiping], np.eye(3))
    w, v = data.truth["w"], data.truth["v"]
    assert np.abs(w[wiping] @ n).max() < 1e-12 and not v[~wiping].any()
    # pressing into the table: the velocity along n is small (~1 mm/s) but not zero
    assert 1e-4 < _rms(v[wiping]) < 0.02 * _rms(w[wiping])
    # the end effector stays on the plane within the pressing depth while wiping, and leaves it
    height = (data.X - np.asarray(data.metadata["plane_point"])) @ n
    assert np.abs(height[wiping]).max() < 1e-3
    assert np.abs(height[~wiping]).max() > 0.05
    # derived velocities follow the true ones
    assert _rms(data.U - (w + v)) < 0.05 * _rms(w + v)
    bias = data.metadata["faults"][0]
    assert bias["kind"] == "force_bias" and len(bias["value"]) == 6


def test_arm_wipe_joint_space():
    data = sim.arm_wipe_joint(n_demos=2, rate=100.0, noise=0.0, compliance=0.0, seed=5)
    log = sim.wipe_log(n_demos=2, rate=100.0, velocity_noise=0.0, compliance=0.0, seed=5)
    wiping = log.phase == WIPE
    assert np.array_equal(data.U, log.dq) and np.array_equal(data.X, log.q)
    A = np.einsum("i,nij->nj", log.normal, SevenDofArm().jacobian(log.q_true)[:, :3, :])
    assert np.abs(np.einsum("nq,nq->n", A, data.U)[wiping]).max() < 1e-12  # nᵀ J_p(q) q̇ = 0
    assert np.abs(np.einsum("nq,nq->n", A, data.U)[~wiping]).max() > 0.05
    N = data.true_projection()
    assert np.allclose(np.einsum("nij,nj->ni", N, data.U), data.U)  # u = N u everywhere
    assert np.allclose(N[~wiping], np.eye(7))
    # the force: the table pushes back while wiping, the bias alone otherwise (plus noise)
    F = log.wrench[:, :3] - log.bias[:3]
    assert np.median(F[wiping] @ log.normal) > 3.0
    assert np.abs(np.median(F[~wiping], 0)).max() < 0.1


def test_free_motion_has_no_constraint():
    reach = sim.free_reach(seed=6)
    assert np.array_equal(reach.truth["N"], np.eye(3)) and "A" not in reach.truth
    assert _rms(reach.U - reach.truth["pi"]) < 0.05 * _rms(reach.truth["pi"])
    ev = np.linalg.eigvalsh(reach.truth["pi"].T @ reach.truth["pi"])
    assert ev[0] / ev.sum() > 0.01  # every direction moves
    strokes = sim.flow2d(seed=7)
    ends = np.flatnonzero(np.r_[strokes.demo[1:] != strokes.demo[:-1], True])
    assert np.abs(strokes.truth["pi"][ends]).max() < 1e-12  # every stroke ends at rest ...
    assert np.abs(strokes.X[ends]).max() < 1e-3  # ... on the goal at the origin
    assert strokes.n_demos == 7 and strokes.X.shape[1] == 2


@pytest.mark.parametrize(("problem", "args", "kwargs"), [
    ("tracker_flips", ["--duration", "20"], {"duration": 20.0}),
    ("tracker_tilt", ["--duration", "30"], {"duration": 30.0}),
    ("arm_wipe", ["--n-demos", "2", "--rate", "50"], {"n_demos": 2, "rate": 50.0}),
    ("arm_wipe_joint", ["--n-demos", "2", "--rate", "50"], {"n_demos": 2, "rate": 50.0}),
    ("free_reach", ["--n-demos", "2"], {"n_demos": 2}),
    ("flow2d", ["--n-demos", "2", "--noise", "0.0002"], {"n_demos": 2, "noise": 2e-4}),
])
def test_simulate_command_writes_the_new_problems(tmp_path, problem, args, kwargs):
    out = tmp_path / f"{problem}.h5"
    assert main(["simulate", problem, "-o", str(out), "--seed", "1", "-q", *args]) == 0
    keep = {"flips": "keep", "spikes": "keep", "stamps": "keep"}  # the recording as written, faults too
    data = load_demonstrations({"files": [str(out)], "faults": keep})
    direct = sim.PROBLEMS[problem](seed=1, **kwargs)
    assert np.allclose(data.X, direct.X) and np.allclose(data.U, direct.U)
    assert np.allclose(data.true_projection(), direct.true_projection())


def test_same_seed_same_recording():
    a, b = sim.tracker_flips(n_spikes=2, duration=20.0, seed=9), sim.tracker_flips(n_spikes=2, duration=20.0,
                                                                                   seed=9)
    assert np.array_equal(a.X, b.X) and a.metadata["faults"] == b.metadata["faults"]
    assert not np.array_equal(a.X, sim.tracker_flips(n_spikes=2, duration=20.0, seed=10).X)
