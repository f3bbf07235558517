"""Sensor faults (ccl_cli/io/faults.py) found against what the simulations injected, no
findings on clean recordings, and the constraint of a repaired tracker recording."""

from pathlib import Path

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.errors import ConfigError
from ccl_cli.io import blockwise, faults, load_demonstrations
from ccl_cli.learn.constraint import StateIndependentConstraint
from ccl_cli.simulate.recordings import TRACKER_ORIGIN, derive

ALL_STAMP_FAULTS = ("repeat", "duplicate", "skip", "step", "back")


def _angle(a: np.ndarray, b: np.ndarray) -> float:
    return float(np.degrees(np.arccos(min(abs(a @ b) / np.linalg.norm(a) / np.linalg.norm(b), 1.0))))


def _normal(U: np.ndarray) -> np.ndarray:
    return StateIndependentConstraint(n_constraints=1).fit(None, U).A_[0]


def test_runs_and_report_of_a_mask():
    mask = np.array([0, 1, 1, 0, 0, 1, 0, 1, 1, 1], bool)
    assert faults.runs(mask).tolist() == [[1, 3], [5, 6], [7, 10]]
    t = np.arange(10) * 0.5
    rep = faults.Finding("spike", mask, "dropped", {"max_z": 9.0}).as_dict(t)
    assert rep == {"kind": "spike", "count": 3, "n_samples": 6, "action": "dropped",
                   "ranges": [[1, 3], [5, 6], [7, 10]], "times": [[0.5, 1.0], [2.5, 2.5], [3.5, 4.5]],
                   "max_z": 9.0}


@pytest.mark.parametrize(("seed", "rate"), [(0, 50.0), (1, 50.0), (2, 200.0)])
def test_every_injected_fault_is_found_where_it_was_injected(seed, rate):
    data = sim.tracker_flips(n_spikes=3, stamp_faults=ALL_STAMP_FAULTS, noise=1e-3, rate=rate, duration=60.0,
                             seed=seed)
    truth = {f["kind"]: f["ranges"] for f in data.metadata["faults"]}
    assert truth["hemisphere_flip"] and len(truth["spike"]) == 3
    cleaned = faults.clean_positions(data.t, data.X, data.demo)
    found = {f["kind"]: f["ranges"] for f in cleaned.report(data.t)}
    for kind in ("hemisphere_flip", "spike", "duplicate_sample", "bad_stamp", "backward_stamp"):
        assert found[kind] == truth[kind], kind
    # a clock step is told from a gap by the motion across it: at rest it is reported as a gap
    step = truth["clock_step"][0]
    assert step in found.get("clock_step", []) + found.get("gap", [])
    assert truth["gap"][0] in found["gap"]
    assert set(found) <= set(truth)
    # repaired: no duplicate, no flip left, stamps increasing at the period except at the gaps
    assert cleaned.keep.sum() == len(data.t) - 1 - 3
    dt = np.diff(cleaned.t)
    assert dt.min() > 0
    gaps = np.sum(dt > 1.5 / rate)
    assert gaps == len(found["gap"]) + len(found["spike"])  # a dropped spike leaves a gap of one period
    normal = data.truth["A"][0]
    U, _ = derive(cleaned.t, cleaned.X, cleaned.demo, rate)
    assert _angle(_normal(U), normal) < 0.5
    assert np.abs(U).max() < 1.0  # the metres-per-second spikes are gone


@pytest.mark.parametrize("seed", [1, 3])
def test_repaired_flips_put_nhat_within_5_degrees_and_raw_ones_do_not(seed):
    data = sim.tracker_flips(seed=seed)
    normal = data.truth["A"][0]
    flips = [f for f in data.metadata["faults"] if f["kind"] == "hemisphere_flip"][0]
    assert flips["count"] == 3 and 45 <= flips["n_samples"] <= 60  # 0.3–0.4 s at 50 Hz each
    assert min(flips["peak_speed"]) > 1.0  # m/s: spikes in the derived velocity
    raw = _angle(_normal(data.U), normal)
    cleaned = faults.clean_positions(data.t, data.X, data.demo)
    U, _ = derive(cleaned.t, cleaned.X, cleaned.demo, 50.0)
    assert raw > 5.0
    assert _angle(_normal(U), normal) < 5.0
    assert np.array_equal(cleaned.X, sim.tracker_plane(seed=seed).X)  # mirrored back exactly


def test_flips_dropped_instead_of_mirrored():
    data = sim.tracker_flips(seed=4, duration=40.0)
    cleaned = faults.clean_positions(data.t, data.X, data.demo, flips="drop")
    flipped = np.zeros(len(data.t), bool)
    for a, b in data.metadata["faults"][0]["ranges"]:
        flipped[a:b] = True
    assert np.array_equal(cleaned.keep, ~flipped)
    assert cleaned.findings[0].action == "dropped"
    kept = faults.clean_positions(data.t, data.X, data.demo, flips="keep")
    assert np.array_equal(kept.X, data.X) and kept.findings[0].action == "reported"
    assert [f.kind for f in kept.findings] == ["hemisphere_flip"]  # its jumps are not spikes
    with pytest.raises(ConfigError, match="flips"):
        faults.clean_positions(data.t, data.X, data.demo, flips="fix")


def test_a_recording_that_starts_mirrored():
    data = sim.tracker_flips(n_flips=2, seed=5, duration=40.0)
    X = -data.X  # the sensor started in the other hemisphere: two long stretches are right
    found = faults.hemisphere_flips(X, data.demo)
    assert found.count == 2  # the two short stretches are the odd ones out: mirrored to match the rest
    repaired = faults.unflip(data.X, faults.hemisphere_flips(data.X, data.demo))
    assert np.allclose(faults.unflip(X, found), -repaired)


CLEAN = {
    "plane 0.2 mm 50 Hz": lambda: sim.tracker_plane(noise=2e-4, duration=40.0, seed=0),
    "plane 2 mm 50 Hz": lambda: sim.tracker_plane(noise=2e-3, duration=40.0, seed=1),
    "plane 1 mm 1 kHz": lambda: sim.tracker_plane(noise=1e-3, rate=1000.0, duration=20.0, seed=2),
    "bowl 0.5 mm 200 Hz": lambda: sim.tracker_sphere(noise=5e-4, rate=200.0, duration=30.0, seed=3),
    "plane 1 mm, jittery stamps": lambda: sim.tracker_plane(jitter=3e-3, duration=40.0, seed=4),
    "around the transmitter": lambda: sim.tracker_flips(n_flips=0, offset=tuple(-TRACKER_ORIGIN),
                                                        duration=40.0, seed=5),
    "arm wipe, task space 200 Hz": lambda: sim.arm_wipe(n_demos=2, seed=6),
    "arm wipe, joints 1 kHz": lambda: sim.arm_wipe_joint(n_demos=1, rate=1000.0, seed=7),
    "reaches": lambda: sim.free_reach(seed=8),
    "strokes to the origin": lambda: sim.flow2d(seed=9),
}


@pytest.mark.parametrize("name", list(CLEAN))
def test_nothing_found_on_clean_recordings(name):
    data = CLEAN[name]()
    cleaned = faults.clean_positions(data.t, data.X, data.demo)
    assert cleaned.findings == []
    assert cleaned.keep.all() and np.array_equal(cleaned.X, data.X) and np.array_equal(cleaned.t, data.t)
    assert not faults.spikes(data.U, data.t, data.demo)  # nor in the (derived or recorded) actions


def test_spikes_in_recorded_actions():
    data = sim.arm_wipe_joint(n_demos=2, rate=100.0, seed=1)
    U = data.U.copy()
    where = np.array([150, 700, 1300])
    U[where, [0, 3, 6]] += 0.1  # rad/s: 50× the velocity noise
    found = faults.spikes(U, data.t, data.demo)
    assert np.flatnonzero(found.mask).tolist() == where.tolist()


def _moving_and_resting(data):
    speed = np.linalg.norm(data.truth["pi"], axis=1)
    moving = int(np.argmax(speed[100:-100])) + 100
    resting = int(np.flatnonzero(speed[100:-100] == 0)[len(np.flatnonzero(speed[100:-100] == 0)) // 2]) + 100
    return moving, resting


def test_clock_steps_are_undone_and_pauses_are_gaps():
    data = sim.tracker_plane(duration=40.0, seed=6)
    moving, resting = _moving_and_resting(data)
    for at, kind in ((moving, "clock_step"), (resting, "gap")):
        t = data.t.copy()
        t[at:] += 0.7
        found, t_new, keep = faults.stamp_faults(t, data.X, data.demo)
        assert [f.kind for f in found] == [kind] and np.flatnonzero(found[0].mask).tolist() == [at]
        assert keep.all()
        assert np.allclose(t_new, data.t if kind == "clock_step" else t)
    back = data.t.copy()
    back[moving:] -= 0.06  # three periods back: stamps not monotonic
    found, t_new, _ = faults.stamp_faults(back, data.X, data.demo)
    assert [f.kind for f in found] == ["backward_stamp"] and np.allclose(t_new, data.t)


@pytest.mark.parametrize("seed", range(5))
def test_a_pause_before_a_stroke_elsewhere_is_a_gap_not_a_clock_step(seed):
    """Strokes recorded one after another in one file (the Trakstar sample): the tool lifts,
    pauses 0.2 s and lands somewhere else still moving. Whatever direction the jump takes,
    that is a gap, never a clock step to undo (nor a spike)."""
    data = sim.tracker_plane(duration=40.0, seed=seed)
    moving, _ = _moving_and_resting(data)
    rng = np.random.default_rng(seed)
    X = data.X.copy()
    jump = rng.normal(size=3)
    X[moving:] += 0.08 * jump / np.linalg.norm(jump)  # lands 8 cm away
    t = data.t.copy()
    t[moving:] += 0.2
    found, t_new, keep = faults.stamp_faults(t, X, data.demo)
    assert [f.kind for f in found] == ["gap"] and np.flatnonzero(found[0].mask).tolist() == [moving]
    assert keep.all() and np.array_equal(t_new, t)


def test_stamp_faults_of_one_sample():
    data = sim.tracker_plane(duration=20.0, seed=7)
    t = data.t.copy()
    t[300] = t[299]  # a repeated stamp
    t[500] = t[500] + 0.013  # a late stamp
    X = np.insert(data.X, 800, data.X[799], axis=0)  # a message recorded twice
    t = np.insert(t, 800, t[799])
    demo = np.zeros(len(t), int)
    found, t_new, keep = faults.stamp_faults(t, X, demo)
    kinds = {f.kind: np.flatnonzero(f.mask).tolist() for f in found}
    assert kinds == {"duplicate_sample": [800], "bad_stamp": [300, 500]}
    assert np.allclose(t_new[keep], data.t)


@pytest.mark.parametrize("bias", [1.0, 0.0])
def test_force_bias_is_reported_not_removed(bias):
    log = sim.wipe_log(n_demos=3, rate=100.0, bias=bias, seed=2)
    found = faults.force_bias(log.wrench, log.t, log.demo)
    assert found.action == "reported"
    value = np.asarray(found.detail["value"])
    if bias:
        assert found.count == 1
        # the free stretches read the bias plus noise: within 4 standard errors of the truth
        assert np.all(np.abs(value - log.bias) < 4 * np.asarray(found.detail["standard_error"]))
        assert np.abs(log.bias).max() > 1.0
    else:
        assert found.count == 0 and not found
        assert np.all(np.abs(value) < 4 * np.asarray(found.detail["standard_error"]))


def test_a_step_is_no_spike():
    """Demonstrations joined without ids (a jump that stays) are not spikes; a spike of the same
    size in the same recording is."""
    data = sim.tracker_plane(noise=1e-3, duration=20.0, seed=3)
    X = data.X.copy()
    X[400:] += [0.05, -0.04, 0.03]  # a 7-cm step
    X[700] += [0.05, -0.04, 0.03]  # a 7-cm spike
    found = faults.spikes(X, data.t, data.demo)
    assert np.flatnonzero(found.mask).tolist() == [700]


@pytest.mark.parametrize("flips", ["mirror", "keep"])
def test_blocked_passes_find_what_one_block_finds_with_faults_on_block_edges(monkeypatch, flips):
    """A recording of several demonstrations, checked in one block on one thread and in
    blocks (on two threads) whose edges fall on the injected spikes and flip boundaries (and
    the samples around them): the same findings and repairs, bit for bit."""
    data = sim.tracker_flips(n_spikes=4, stamp_faults=ALL_STAMP_FAULTS, noise=1e-3, rate=200.0,
                             duration=60.0, seed=6)
    demo = np.repeat(np.arange(3), [4000, 4000, len(data.t) - 8000])
    truth = {f["kind"]: f["ranges"] for f in data.metadata["faults"]}
    monkeypatch.setattr(blockwise, "BLOCK_ROWS", 10 * len(data.t))  # the whole recording at once
    monkeypatch.setattr(blockwise, "cores", lambda: 1)
    whole = faults.clean_positions(data.t, data.X, demo, flips=flips)
    found = {f["kind"]: f["ranges"] for f in whole.report(data.t)}
    assert found["spike"] == truth["spike"]
    if flips == "mirror":
        assert found["hemisphere_flip"] == truth["hemisphere_flip"]
    in_actions = faults.spikes(data.U, data.t, demo)
    edges = [a for a, _ in truth["spike"]] + [e for r in truth["hemisphere_flip"] for e in r]
    sizes = {size for e in edges for size in (e - 3, e - 2, e - 1, e) if size > 0} | {997, 4096}
    monkeypatch.setattr(blockwise, "cores", lambda: 2)
    for size in sorted(sizes):
        monkeypatch.setattr(blockwise, "BLOCK_ROWS", size)
        blocked = faults.clean_positions(data.t, data.X, demo, flips=flips)
        assert blocked.report(data.t) == whole.report(data.t), size
        assert np.array_equal(blocked.X, whole.X) and np.array_equal(blocked.t, whole.t)
        assert np.array_equal(blocked.keep, whole.keep)
        again = faults.spikes(data.U, data.t, demo)
        assert np.array_equal(again.mask, in_actions.mask) and again.detail == in_actions.detail


def test_block_passes_use_the_cores_a_batch_worker_was_given(monkeypatch):
    """A batch shares the cores between its workers through OMP_NUM_THREADS (and the like):
    the block passes take no more threads than that, and at least one."""
    monkeypatch.setattr(blockwise.os, "sched_getaffinity", lambda pid: {0, 1, 2, 3}, raising=False)
    for var in blockwise.THREAD_VARS:
        monkeypatch.delenv(var, raising=False)
    assert blockwise.cores() == 4
    monkeypatch.setenv("OPENBLAS_NUM_THREADS", "2")
    assert blockwise.cores() == 2
    monkeypatch.setenv("OMP_NUM_THREADS", "1")
    assert blockwise.cores() == 1
    monkeypatch.setenv("OMP_NUM_THREADS", "16")  # never more than the machine gives
    assert blockwise.cores() == 4
    monkeypatch.setenv("OMP_NUM_THREADS", "x")  # not a count: the next variable
    assert blockwise.cores() == 2


def test_each_block_raises_what_a_block_raised():
    def work(s, e):
        if s <= 5 < e:
            raise ValueError(f"block {s}")

    with pytest.raises(ValueError, match="block 4"):
        blockwise.each_block(work, 0, 12, rows=4)
    assert blockwise.blocks(2, 11, rows=4) == [(2, 6), (6, 10), (10, 11)]


def test_median_is_numpys():
    """faults._median (no numpy.ma import) gives np.median's value, NaN included, for odd and
    even counts and values spread over many orders of magnitude."""
    rng = np.random.default_rng(5)
    for n in (1, 2, 3, 4, 7, 10, 1001, 4096):
        for trial in range(12):
            values = rng.standard_normal(n) * 10.0 ** rng.uniform(-200, 200, n)
            if trial % 4 == 1:
                values[rng.integers(n)] = np.nan
            if trial % 4 == 2:
                values[rng.integers(n)] = -np.inf
            want = np.median(values)
            got = faults._median(values.copy())
            assert isinstance(got, float)
            assert (np.isnan(want) and np.isnan(got)) or got == want, (n, trial)


ARTICULATION = Path(__file__).resolve().parent.parent / "sample_data" / "articulation"


@pytest.mark.parametrize("mechanism", ["dishwasher", "drawer"])
@pytest.mark.parametrize("unit", [1.0, 1000.0])
def test_the_real_articulation_logs_lose_no_sample(mechanism, unit):
    """Robot end-effector logs (TUM, no stamps, 10 Hz assumed) paced unevenly — a step of 7 mm, then
    three of < 1 mm — in metres and in millimetres: no sample is a spike (the two samples of
    dishwasher/007.log that were dropped lie on the path their neighbours trace, up to 1.4
    periods from where the even pace puts them)."""
    files = sorted((ARTICULATION / mechanism).glob("*.log"))
    data = load_demonstrations({"state": {"columns": [0, 1, 2]}, "action": {"derive": "state"},
                                "time": {"rate": 10}}, files=files)
    assert data.repair.counts() == {"kept": {"": data.n_samples}}
    cleaned = faults.clean_positions(data.t, data.X * unit, data.demo)
    assert cleaned.findings == []


def _jittered_arc(seed: int, n: int = 3000, rate: float = 100.0) -> tuple[np.ndarray, np.ndarray]:
    """An end effector drawing circles of 5 cm radius at 0.2 m/s, positions smooth to 1 µm, one
    sample in ten taken 2–5 % of a period late, all stamped on the even grid: (t (n,), X (n, 3))
    in s and m."""
    rng = np.random.default_rng(seed)
    t = np.arange(n) / rate
    late = np.where(rng.random(n) < 0.1, rng.uniform(0.02, 0.05, n), 0.0) / rate
    angle = 0.2 / 0.05 * (t + late)
    X = np.c_[0.05 * np.cos(angle), 0.05 * np.sin(angle), 0.01 * np.sin(0.5 * angle)]
    return t, X + rng.normal(scale=1e-6, size=X.shape)


@pytest.mark.parametrize("seed", [0, 1])
def test_timing_on_a_smooth_path_is_no_spike_and_a_spike_off_it_is(seed):
    """A smooth log (1 µm noise) whose samples are taken a little early or late leaves residuals
    tens of noise deviations along the path: timing, kept. A sample 4 mm off the path (two
    periods' motion) is a spike, found alone — in metres and in millimetres."""
    t, X = _jittered_arc(seed)
    demo = np.zeros(len(t), int)
    assert faults.spikes(X, t, demo).detail["max_z"] > 30  # far beyond the noise ...
    assert not faults.spikes(X, t, demo)  # ... and on the path
    tangent = np.array([-np.sin(4.0 * t[1500]), np.cos(4.0 * t[1500]), 0.0])
    X[1500] += 0.004 * np.cross(tangent, [0.0, 0.0, 1.0])
    for unit in (1.0, 1000.0):
        assert np.flatnonzero(faults.spikes(X * unit, t, demo).mask).tolist() == [1500]


@pytest.mark.parametrize("unit", [1.0, 1000.0])
def test_a_quantised_log_moving_slowly_has_no_spike_until_one_is_put_in(unit):
    """Joint positions written to 10⁻⁴ rad (an encoder's count) of an arm at 1 kHz, one joint
    crawling (most of its residuals are exactly 0, so their MAD is 0): its one-count toggles are
    no spikes (the noise is at least the rounding's, q/√12); a jump of 20 counts is."""
    t = np.arange(20000) / 1000.0
    rng = np.random.default_rng(0)
    X = 0.5 * np.c_[np.sin(0.3 * t), 0.2 * np.cos(0.2 * t)] + rng.normal(scale=2e-6, size=(len(t), 2))
    X = np.round(X / 1e-4) * 1e-4 * unit
    demo = np.zeros(len(t), int)
    assert faults.clean_positions(t, X, demo).findings == []
    X[12345, 1] += 20e-4 * unit
    assert np.flatnonzero(faults.spikes(X, t, demo).mask).tolist() == [12345]
