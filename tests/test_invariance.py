"""The answer does not depend on how a recording is written (issue 30, item 4): learn-a's defaults,
end to end through the readers (``ccl learn-a`` in-process), give the same number of constraints
and the same rows at every sample — median within 1°, 95 % of the samples within 2° — when

* the rate of a file without stamps is assumed at 10, 30 or 100 Hz (``time: {rate: ...}``);
* the time column is in s, ms or ns (``time: {column: t, unit: ...}``);
* the positions are in m, mm or km;
* the frame is rotated and translated;
* the files, or the demonstrations in one file, come in another order.

On the shipped real logs (sample_data/articulation: a dishwasher door and a drawer, BSD) and on
the simulations of ccl_cli/simulate (a hinge, a slide, handwriting, reaching; files written by
``ccl simulate`` and rewritten transformed). Where a property fails today the case is an
``xfail(strict=True)`` naming the cause, so that a fix shows.

The held-out test split ranks the demonstrations it holds out whole by their shape
(``splitters.shape_keys``), so the same logs are held out in any order; under 5 demonstrations
it holds out contiguous time blocks in the samples' order, which another order changes (a
strict xfail below). The order is checked with the split on, and with ``data.test.fraction: 0``
(what is learnt from the same data).

Examples per property: ``CCL_INVARIANCE_EXAMPLES`` (default 2; the report's figures: 25).
"""

from __future__ import annotations

import csv
import os
from collections.abc import Callable
from dataclasses import dataclass, replace
from pathlib import Path

import numpy as np
import pytest
from hypothesis import HealthCheck, given, settings
from hypothesis import strategies as st
from learnt import Learnt, by_position, largest_angles, learn_a

from ccl_cli.cli import main
from ccl_cli.io import load_demonstrations, write_demonstrations

ARTICULATION = Path(__file__).resolve().parent.parent / "sample_data" / "articulation"
EXAMPLES = int(os.environ.get("CCL_INVARIANCE_EXAMPLES", "2"))
#: Faults kept as recorded when a file is read to be rewritten transformed (learn-a repairs them).
KEEP = {"flips": "keep", "spikes": "keep", "stamps": "keep"}
#: Rows within MEDIAN_DEG (median over samples) and 95 % of the samples within P95_DEG.
MEDIAN_DEG, P95_DEG = 1.0, 2.0
#: A log read as plain text: columns x, y, z, no time (a rate assumed), one demonstration a file.
TEXT = {"state": {"columns": [0, 1, 2]}, "action": {"derive": "state"}, "time": {"rate": 10}}
PROPERTY = settings(max_examples=EXAMPLES, deadline=None,
                    suppress_health_check=[HealthCheck.too_slow, HealthCheck.data_too_large])


@dataclass
class Case:
    """A recording as files: ``parts`` the positions of each file (text logs, q columns) or None
    for one canonical HDF5 file ``files[0]``; ``data`` the config's data mapping."""

    name: str
    files: list[Path]
    data: dict | None
    parts: list[np.ndarray] | None = None


def _text(parts: list[np.ndarray], folder: Path, q: int = 3) -> Case:
    folder.mkdir(parents=True, exist_ok=True)
    files = []
    for i, P in enumerate(parts):
        files.append(folder / f"{i:03d}.log")
        np.savetxt(files[-1], P, fmt="%.17g")
    return Case(folder.name, files, {**TEXT, "state": {"columns": list(range(q))}}, parts)


def _simulated(problem: str, folder: Path, *args: str, seed: int = 3) -> Path:
    folder.mkdir(parents=True, exist_ok=True)
    out = folder / f"{problem}.h5"
    assert main(["simulate", problem, "-o", str(out), "--seed", str(seed), "-q", "--force", *args]) == 0
    return out


def _real(kind: str, folder: Path) -> Case:
    # 5 of the 8 logs (a test of modest size; with 4 the held-out split cuts time blocks instead of
    # holding out whole logs — learn-a finds k = 2 on such subsets of the dishwasher too, but they
    # test the split in time, not whole logs held out)
    files = [sorted((ARTICULATION / kind).glob("*.log"))[i] for i in (0, 2, 4, 6, 7)]
    return Case(kind, files, TEXT, [np.loadtxt(f) for f in files])


def _as_text(problem: str, folder: Path, *args: str, seed: int = 3) -> Case:
    """A simulation's positions written as plain-text logs without time, one per demonstration."""
    written = _simulated(problem, folder / "h5", *args, seed=seed)
    d = load_demonstrations({"files": [str(written)], "faults": KEEP})
    return _text([d.X[d.demo == i] for i in d.demo_ids], folder / f"{problem}_text", d.n_state)


MAKERS: dict[str, Callable[[Path], Case]] = {
    "dishwasher": lambda p: _real("dishwasher", p),
    "drawer": lambda p: _real("drawer", p),
    "hinge": lambda p: Case("hinge", [_simulated("hinge", p)], None),
    "slide": lambda p: Case("slide", [_simulated("slide", p, "--n-demos", "4")], None),
    "handwriting": lambda p: Case("handwriting", [_simulated("handwriting", p)], None),
    "reach_goal": lambda p: Case("reach_goal", [_simulated("reach_goal", p, "--n-demos", "4")], None),
    "contact_phases": lambda p: Case("contact_phases", [_simulated("contact_phases", p, "--n-demos", "3",
                                                                   seed=0)], None),
    "hinge text": lambda p: _as_text("hinge", p),
    "slide text": lambda p: _as_text("slide", p, "--n-demos", "4"),
    "handwriting text": lambda p: _as_text("handwriting", p),
    "reach_goal text": lambda p: _as_text("reach_goal", p, "--n-demos", "2"),
    "contact_phases text": lambda p: _as_text("contact_phases", p, "--n-demos", "3", seed=0),
}


class Runs:
    """Cases and their learn-a answers, made once per test session."""

    def __init__(self, root: Path) -> None:
        self.root = root
        self.cases: dict[str, Case] = {}
        self.answers: dict[str, Learnt] = {}
        self.count = 0

    def case(self, name: str) -> Case:
        if name not in self.cases:
            self.cases[name] = MAKERS[name](self.root / name.replace(" ", "_"))
        return self.cases[name]

    def base(self, name: str) -> Learnt:
        if name not in self.answers:
            case = self.case(name)
            self.answers[name] = learn_a(case.files, self.root / f"{name.replace(' ', '_')}_base", case.data)
            assert self.answers[name].code == 0, self.answers[name].summary
        return self.answers[name]

    def folder(self) -> Path:
        self.count += 1
        return self.root / f"run{self.count}"

    def learn(self, files: list[Path], data: dict | None) -> Learnt:
        got = learn_a(files, self.folder(), data)
        assert got.code == 0, got.summary
        return got


@pytest.fixture(scope="module")
def runs(tmp_path_factory) -> Runs:
    return Runs(tmp_path_factory.mktemp("invariance"))


def assert_same(base: Learnt, other: Learnt, what: str, back: np.ndarray | None = None,
                reordered: bool = False) -> None:
    """The same k and rows (module docstring); ``back`` (q, q) maps the other frame's rows back
    (rows · back), ``reordered``: the samples are matched by their states."""
    assert other.k == base.k, f"{what}: k {base.k} → {other.k} ({base.chose} → {other.chose})"
    assert other.data.n_samples == base.data.n_samples, (
        f"{what}: {base.data.n_samples} → {other.data.n_samples} samples kept")
    R1, R2 = base.rows, other.rows
    if back is not None:
        R2 = [r @ back for r in R2]
    if reordered:
        R1 = [R1[i] for i in by_position(base.data)]
        R2 = [R2[i] for i in by_position(other.data)]
    angles = largest_angles(R1, R2)
    assert np.median(angles) <= MEDIAN_DEG and np.percentile(angles, 95) <= P95_DEG, (
        f"{what}: k = {base.k}, rows {np.median(angles):.2f}° apart (median), "
        f"{np.percentile(angles, 95):.2f}° (95th percentile), {base.chose} → {other.chose}")


def rotation(a: float, b: float, c: float, q: int = 3) -> np.ndarray:
    def r(i: int, j: int, t: float) -> np.ndarray:
        R = np.eye(3)
        R[[i, i, j, j], [i, j, i, j]] = [np.cos(t), -np.sin(t), np.sin(t), np.cos(t)]
        return R
    R = r(0, 1, a) @ r(1, 2, b) @ r(0, 2, c)
    return R if q == 3 else r(0, 1, a)[:2, :2]


def rewritten(runs: Runs, name: str, positions: Callable[[np.ndarray], np.ndarray],
              velocities: Callable[[np.ndarray], np.ndarray] | None = None,
              order: np.ndarray | None = None) -> tuple[list[Path], dict | None]:
    """The case's files written again with positions (and stored velocities) mapped, files (text)
    or demonstrations (HDF5) in ``order``."""
    case = runs.case(name)
    folder = runs.folder()
    if case.parts is not None:
        parts = [case.parts[i] for i in (order if order is not None else range(len(case.parts)))]
        moved = _text([positions(P) for P in parts], folder, case.parts[0].shape[1])
        return moved.files, case.data
    d = load_demonstrations({"files": [str(case.files[0])], "faults": KEEP})
    # the truth is left out: it was not written in the new frame (and learning never reads it)
    d = replace(d, X=positions(d.X), U=(velocities or positions)(d.U), truth={})
    if order is not None:
        d = d.subset(np.concatenate([np.flatnonzero(d.demo == i) for i in order]))
    how = d.derivative
    folder.mkdir(parents=True)
    out = write_demonstrations(folder / "moved.h5", d, provenance={"derivative": {
        "window": how.window, "order": how.order}} if how.derived else {})
    return [out], None


# -- an assumed rate ---------------------------------------------------------------------------
RATE_CASES = ["dishwasher", "drawer", "hinge text", "slide text", "handwriting text"]


@PROPERTY
@given(name=st.sampled_from(RATE_CASES), rate=st.sampled_from([30.0, 100.0, 3.0, 250.0]))
def test_an_assumed_rate_does_not_change_the_answer(runs, name, rate):
    case = runs.case(name)
    other = runs.learn(case.files, {**case.data, "time": {"rate": rate}})
    assert_same(runs.base(name), other, f"{name} at {rate:g} Hz (10 Hz assumed first)")


@pytest.mark.xfail(strict=True, reason=(
    "the states' geometry finds no constraint at either rate, and then learn-a's velocity candidates run: "
    "per_window (4-s windows, learn/constraint/auto.py) is tried when its windows hold ≥ 70 samples: at "
    "an assumed 10 Hz they hold 40 (not tried, k = 0), at 30 Hz 120 and it claims one constraint in free "
    "reaching (k 0 → 1, noise ratio 7.7 below the limit 10); the window is in seconds of a rate nobody "
    "measured"))
def test_an_assumed_rate_on_free_reaching(runs):
    case = runs.case("reach_goal text")
    assert_same(runs.base("reach_goal text"), runs.learn(case.files, {**case.data, "time": {"rate": 30.0}}),
                "reach_goal text at 30 Hz")


@pytest.mark.xfail(strict=True, reason=(
    "the states' geometry finds the same phases at every rate (the stretches that come back over their "
    "ground: 58 % of the samples, learn/constraint/geometry.py), but the model auto fits on them "
    "(auto.py _manifold_model, scope phases) is ConstraintInStretches, which finds again where the rows "
    "hold in blocks of BLOCK_S = 0.5 s (learn/constraint/stretches.py): at an assumed 100 Hz they hold in "
    "25 % of the samples, at 10 Hz in 46 %"))
def test_an_assumed_rate_on_a_surface_worked_in_phases(runs):
    case = runs.case("contact_phases text")
    assert_same(runs.base("contact_phases text"),
                runs.learn(case.files, {**case.data, "time": {"rate": 100.0}}),
                "contact_phases text at 100 Hz")


# -- the time unit ------------------------------------------------------------------------------
@pytest.mark.parametrize("unit", ["ms", "ns"])
def test_the_time_unit_of_a_column_does_not_change_the_answer(runs, unit):
    """A CSV per demonstration with a time column in s, and the same in ms or ns."""
    case = runs.case("hinge")
    d = load_demonstrations({"files": [str(case.files[0])], "faults": KEEP})
    scale = {"s": 1.0, "ms": 1e3, "ns": 1e9}

    def write(u: str) -> list[Path]:
        folder = runs.folder()
        folder.mkdir()
        files = []
        for i in d.demo_ids:
            m = d.demo == i
            files.append(folder / f"demo{i}.csv")
            with files[-1].open("w", newline="") as f:
                w = csv.writer(f)
                w.writerow(["t", "x", "y", "z"])
                stamps = np.round(d.t[m] * scale[u]).astype(np.int64) if u == "ns" else d.t[m] * scale[u]
                rows = zip(stamps.tolist(), d.X[m].tolist(), strict=True)
                w.writerows([[repr(s), *map(repr, x)] for s, x in rows])
        return files

    config = {"state": {"columns": ["x", "y", "z"]}, "action": {"derive": "state"}}
    seconds = runs.learn(write("s"), {**config, "time": {"column": "t", "unit": "s"}})
    other = runs.learn(write(unit), {**config, "time": {"column": "t", "unit": unit}})
    assert_same(seconds, other, f"time in {unit} (s first)")
    assert seconds.k == 2


# -- the length unit ----------------------------------------------------------------------------
UNIT_CASES = ["dishwasher", "drawer", "hinge", "slide", "handwriting", "reach_goal", "contact_phases"]


@PROPERTY
@given(name=st.sampled_from(UNIT_CASES), scale=st.sampled_from([1e3, 1e-3, 1e2]))
def test_the_length_unit_does_not_change_the_answer(runs, name, scale):
    files, data = rewritten(runs, name, lambda X: X * scale)
    assert_same(runs.base(name), runs.learn(files, data), f"{name} × {scale:g}")


# -- the frame ----------------------------------------------------------------------------------
@PROPERTY
@given(name=st.sampled_from(UNIT_CASES), angles=st.tuples(*[st.floats(-np.pi, np.pi)] * 3),
       shift=st.tuples(*[st.floats(-5.0, 5.0)] * 3))
def test_a_rotated_and_translated_frame_does_not_change_the_answer(runs, name, angles, shift):
    q = 2 if name == "handwriting" else 3
    R = rotation(*angles, q=q)
    t = np.asarray(shift[:q])
    files, data = rewritten(runs, name, lambda X: X @ R.T + t, lambda U: U @ R.T)
    assert_same(runs.base(name), runs.learn(files, data), f"{name} rotated by {np.round(angles, 3)} rad, "
                f"shifted by {np.round(t, 3)} m", back=R)


# -- the order of files and demonstrations ----------------------------------------------------------
#: Cases checked with the split on: 5 demonstrations or more (held out by shape, the same in any
#: order), or under 5 (handwriting, reach_goal: blocks in file order) with no constraint in any.
ORDER_CASES = ["hinge", "handwriting", "reach_goal", "dishwasher", "drawer", "slide"]
#: The same cases with the split off: what is learnt from the same data.
ORDER_CASES_NO_SPLIT = ["dishwasher", "drawer", "slide", "contact_phases"]
NO_SPLIT = {"test": {"fraction": 0}}


def reordered(runs: Runs, name: str, order: np.ndarray, split: bool) -> tuple[Learnt, Learnt]:
    """The case's answer (with the held-out split, or with ``data.test.fraction: 0``) and the
    answer with its files or demonstrations in ``order``."""
    files, config = rewritten(runs, name, lambda X: X, order=order)
    if split:
        return runs.base(name), runs.learn(files, config)
    case = runs.case(name)
    key = f"{name} no split"
    if key not in runs.answers:
        runs.answers[key] = runs.learn(case.files, {**(case.data or {}), **NO_SPLIT})
    return runs.answers[key], runs.learn(files, {**(config or {}), **NO_SPLIT})


def _order(runs: Runs, name: str, data: st.DataObject) -> np.ndarray:
    case = runs.case(name)
    n = len(case.parts) if case.parts is not None else runs.base(name).data.n_demos
    return np.asarray(data.draw(st.permutations(range(n))))


@PROPERTY
@given(name=st.sampled_from(ORDER_CASES), data=st.data())
def test_the_order_of_files_and_demonstrations_does_not_change_the_answer(runs, name, data):
    order = _order(runs, name, data)
    assert_same(*reordered(runs, name, order, split=True), f"{name} in the order {order.tolist()}",
                reordered=True)


@PROPERTY
@given(name=st.sampled_from(ORDER_CASES_NO_SPLIT), data=st.data())
def test_the_order_does_not_change_what_is_learnt_from_the_same_data(runs, name, data):
    order = _order(runs, name, data)
    assert_same(*reordered(runs, name, order, split=False), f"{name} in the order {order.tolist()}, "
                "data.test.fraction: 0", reordered=True)


# The orders that held out other demonstrations while the split went by position (logs 005 and
# 008 of the drawer instead of 007 and 008; the dishwasher's 003 and 005 took one family of spheres
# instead of a circle per log, rows 7.7° apart at the 95th percentile): the split now ranks
# demonstrations by their shape (splitters.shape_keys).
def test_the_order_of_files_with_the_split_on_the_drawer(runs):
    assert_same(*reordered(runs, "drawer", np.array([0, 1, 3, 2, 4]), split=True), "drawer in the order "
                "[0, 1, 3, 2, 4]", reordered=True)


@pytest.mark.xfail(strict=True, reason=(
    "under 5 demonstrations the held-out split is contiguous time blocks of the samples in file order "
    "(learn/model_selection/splitters.py holdout_split): another order holds out other samples. Blocks "
    "inside each demonstration, or laid over them ranked by shape, are order-free but cut the arcs of "
    "3 hinge logs (the left door) short enough to hide their common circle (k 2 → 1); a surface worked "
    "in phases, 3 demonstrations in the order [2, 0, 1]: k 1 → 0"))
def test_the_order_of_demonstrations_with_the_split_on_a_surface_worked_in_phases(runs):
    assert_same(*reordered(runs, "contact_phases", np.array([2, 0, 1]), split=True),
                "contact_phases in the order [2, 0, 1]", reordered=True)


def test_the_order_of_files_with_the_split_on_the_dishwasher(runs):
    assert_same(*reordered(runs, "dishwasher", np.array([0, 3, 4, 1, 2]), split=True), "dishwasher in the "
                "order [0, 3, 4, 1, 2]", reordered=True)


@settings(max_examples=25, deadline=None)
@given(seed=st.integers(0, 2**16), n_demos=st.integers(5, 9), scale=st.sampled_from([1.0, 1e3, 0.0254]))
def test_the_held_out_split_follows_the_demonstrations_not_their_order_frame_or_unit(seed, n_demos, scale):
    """The same demonstrations are held out whatever order they come in, and in any frame or length
    unit (≥ 5 of them; fewer are split in time blocks of the samples' order)."""
    from scipy.spatial.transform import Rotation

    from ccl_cli.learn.model_selection import holdout_split, shape_keys

    rng = np.random.default_rng(seed)
    sizes = rng.integers(60, 200, size=n_demos)  # (5 or more: by demonstration)
    demo = np.repeat(np.arange(n_demos), sizes)
    X = rng.normal(size=(len(demo), 3)) * rng.uniform(0.1, 2.0, size=(n_demos, 3))[demo]
    order = rng.permutation(n_demos)
    rows = np.concatenate([np.flatnonzero(demo == i) for i in order])  # the demonstrations reordered
    demo2 = np.repeat(np.arange(n_demos), sizes[order])  # ids renumbered in their new order
    R = Rotation.random(random_state=seed).as_matrix()
    X2 = scale * X[rows] @ R.T + rng.normal(size=3)
    a = holdout_split(demo, 0.3, seed=3, gap=2, keys=shape_keys(X, demo))
    b = holdout_split(demo2, 0.3, seed=3, gap=2, keys=shape_keys(X2, demo2))
    assert a.info["kind"] == "demonstrations"
    assert np.array_equal(a.test[rows], b.test) and np.array_equal(a.train[rows], b.train)
