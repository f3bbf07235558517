"""A constraint that holds in some stretches of a recording only, on whole wiping recordings —
approach (free), wipe (on a tilted table), retract (free) — against the simulation's ground truth:
by default learn-a's ``auto`` reads the phases and the table from the positions
(ccl_cli/learn/constraint/manifold_phases.py, ``ManifoldInPhases``); from the velocities alone it
chooses the constraint in stretches (stretches.py, ``ConstraintInStretches``). Free motion keeps
k = 0. The many-seed bars are in benchmarks/bench_auto.py (wipe_whole*, free_reach, flow2d)."""

import h5py
import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.app.scoring import applied_on, projection_on
from ccl_cli.errors import InputError
from ccl_cli.learn.constraint import AutoConstraint, ConstraintInStretches, ManifoldInPhases
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.learn.constraint import stretches as st
from ccl_cli.learn.constraint.auto import CANDIDATES
from ccl_cli.metrics import subspace_angle
from ccl_cli.models import load_model, save_model


def fit_auto(d, **kw) -> AutoConstraint:
    derivative = d.metadata.get("derivative", False)
    return AutoConstraint(**kw).fit(d.X, d.U, groups=d.demo, t=d.t, derivative=derivative)


#: auto's candidates but the states' geometry: the velocities alone decide.
VELOCITY = [c for c in CANDIDATES if c != "manifold"]


def row_of(model: AutoConstraint, name: str) -> dict:
    return next(r for r in model.selection_["candidates"] if r["class"] == name)


def wiping(d) -> np.ndarray:
    """True where a sample of an arm_wipe recording is in its wipe phase."""
    return np.abs(d.true_projection() - np.eye(3)).max((1, 2)) > 0


@pytest.fixture(scope="module")
def wipe():
    return sim.arm_wipe(n_demos=6, seed=1)


@pytest.fixture(scope="module")
def wipe_model(wipe):
    """auto from the velocities alone: the constraint in stretches."""
    return fit_auto(wipe, candidates=VELOCITY)


def test_whole_wipe_recording_gets_the_table_in_its_phases_from_the_positions(wipe):
    model = fit_auto(wipe)
    assert model.n_constraints_ == 1 and model.selection_["chosen"] == "manifold"
    inner = model.model_
    assert isinstance(inner, ManifoldInPhases) and inner.family == "linear"
    assert subspace_angle(inner.constant_rows(), np.atleast_2d(wipe.metadata["normal"])) < 0.5
    # the states: no surface holds all along (the approach and retract leave the table), one holds
    # in the stretches that come back over their ground — the wipes
    shapes = model.selection_["geometry"]["models"]
    assert not any(r["holds"] for r in shapes if r["scope"] != "phases")
    phases = next(r for r in shapes if r["scope"] == "phases")
    assert phases["chosen"] and phases["holds"] and phases["k"] == 1 and phases["drift"][0] < 0.1
    # where it holds: at the level of a wipe, against the truth sample by sample
    on = model.holds(wipe.X, groups=wipe.demo, t=wipe.t)
    truth = wiping(wipe)
    assert (on == truth).mean() > 0.9 and abs(inner.share_ - truth.mean()) < 0.1
    N = model.projection(wipe.X, groups=wipe.demo, t=wipe.t)
    assert (np.abs(N - wipe.true_projection()).max((1, 2)) < 0.05).mean() > 0.9
    assert np.allclose(N[~on], np.eye(3))
    assert "free motion elsewhere" in model.selection_["reason"]


def test_the_phases_of_the_same_data_are_found_once_per_model(wipe, monkeypatch):
    """Where a surface in phases holds is asked for again and again (evidence, scores, report):
    the phases of each data set are found once, by the contents of the states and ids — not
    by their objects — and the answers are the same (6·10⁵ samples: learn-a 8.1 → 4.4 s CPU)."""
    from ccl_cli.learn.constraint import manifold_phases as mp

    calls: list[int] = []
    real = mp.contact_runs
    monkeypatch.setattr(mp, "contact_runs", lambda X, g: calls.append(len(X)) or real(X, g))
    model = fit_auto(wipe).model_
    assert isinstance(model, ManifoldInPhases) and calls.count(wipe.n_samples) == 1  # in fit
    half = wipe.demo < np.median(wipe.demo)
    first = model.holds(wipe.X, groups=wipe.demo)
    for _ in range(3):
        again = model.holds(wipe.X.copy(), groups=wipe.demo.copy())  # the same contents, new arrays
        part = model.holds(wipe.X[half], groups=wipe.demo[half])
    assert calls.count(wipe.n_samples) == 1 and calls.count(int(half.sum())) == 1
    assert np.array_equal(first, again) and np.array_equal(part, real_holds(model, wipe, half))
    moved = wipe.X + 1e-3  # other contents: found anew
    model.holds(moved, groups=wipe.demo)
    assert calls.count(wipe.n_samples) == 2


def real_holds(model, d, rows) -> np.ndarray:
    """``model.holds`` of d's rows computed without the kept phases."""
    from ccl_cli.learn.constraint import geometry

    X, g = d.X[rows], d.demo[rows]
    return model._on(model.levels(X), g, geometry.contact_runs(X, g))


def test_whole_wipe_recording_gets_the_table_in_its_stretches(wipe, wipe_model):
    model = wipe_model
    assert model.n_constraints_ == 1 and model.selection_["chosen"] == "stretches"
    inner = model.model_
    assert isinstance(inner, ConstraintInStretches)
    assert subspace_angle(inner.A_, np.atleast_2d(wipe.metadata["normal"])) < 1.5
    assert inner.share_ >= st.MIN_SHARE
    # where it holds: the wipe phase, against the truth sample by sample
    on = inner.holds(wipe.X, groups=wipe.demo, t=wipe.t)
    truth = wiping(wipe)
    assert (on == truth).mean() > 0.9
    assert abs(inner.share_ - truth.mean()) < 0.1
    # Ñ = I − nnᵀ where it holds, I elsewhere: the true projection almost everywhere
    N = model.projection(wipe.X, groups=wipe.demo, t=wipe.t)
    assert (np.abs(N - wipe.true_projection()).max((1, 2)) < 0.05).mean() > 0.9
    assert np.allclose(N[~on], np.eye(3))
    # the words say where: "k = 1 in 7x % of the moving time: demo 0 1.5–..."
    assert "k = 1 in" in model.selection_["reason"] and "free motion elsewhere" in model.selection_["reason"]


@pytest.mark.parametrize("rate", [50.0, 1000.0])
def test_whole_wipe_at_other_rates(rate):
    d = sim.arm_wipe(n_demos=5, rate=rate, seed=2)
    normal = np.atleast_2d(d.metadata["normal"])
    model = fit_auto(d)
    assert model.n_constraints_ == 1 and isinstance(model.model_, ManifoldInPhases)
    assert subspace_angle(model.model_.constant_rows(), normal) < 0.5
    assert (model.holds(d.X, groups=d.demo, t=d.t) == wiping(d)).mean() > 0.9
    velocity = fit_auto(d, candidates=VELOCITY)
    assert velocity.n_constraints_ == 1 and velocity.selection_["chosen"] == "stretches"
    assert subspace_angle(velocity.model_.A_, normal) < 1.5


def test_whole_wipe_with_a_biased_and_drifting_position_sensor():
    d = sim.arm_wipe(n_demos=5, offset=0.01, drift=2e-4, seed=4)
    assert d.metadata["position_bias"]["drift_m_s"] == 2e-4
    normal = np.atleast_2d(d.metadata["normal"])
    model = fit_auto(d)
    assert model.n_constraints_ == 1 and isinstance(model.model_, ManifoldInPhases)
    assert subspace_angle(model.model_.constant_rows(), normal) < 1.5
    velocity = fit_auto(d, candidates=VELOCITY)
    assert velocity.n_constraints_ == 1 and velocity.selection_["chosen"] == "stretches"
    assert subspace_angle(velocity.model_.A_, normal) < 1.5


@pytest.mark.parametrize("make", [lambda s: sim.free_reach(seed=s), lambda s: sim.flow2d(seed=s)],
                         ids=["free_reach", "flow2d"])
@pytest.mark.parametrize("seed", [5, 6])
def test_free_motion_gets_no_constraint_from_lucky_stretches(make, seed):
    d = make(seed)
    model = fit_auto(d)
    assert model.n_constraints_ == 0 and model.selection_["chosen"] == "none"
    row = row_of(model, "stretches")
    assert row["k"] == 0 and row["time_share"] < st.MIN_SHARE
    # on its own training data a row quiet in some stretches exists, in far fewer than the table's
    inner = ConstraintInStretches(n_constraints=1).fit(d.X, d.U, groups=d.demo, t=d.t,
                                                       derivative=d.derivative)
    assert 0 < inner.share_ < st.MIN_SHARE


def test_a_constraint_holding_all_along_keeps_its_global_model():
    model = fit_auto(sim.tracker_plane(duration=40.0, seed=5))
    assert model.selection_["chosen"] == "nhat"
    assert not any(r["scope"] == "phases" and r["holds"] for r in model.selection_["geometry"]["models"])
    velocity = fit_auto(sim.tracker_plane(duration=40.0, seed=5),
                        candidates=[c for c in CANDIDATES if c != "manifold"])
    assert velocity.selection_["chosen"] == "nhat"
    assert row_of(velocity, "stretches")["reason"].startswith("not tried: 1 constraint(s) hold")


def test_saved_model_loads_and_classifies_new_demonstrations_of_the_same_table(tmp_path):
    d = sim.arm_wipe(n_demos=8, seed=0)
    train, new = d.subset(d.demo < 6), d.subset(d.demo >= 6)
    model = fit_auto(train, candidates=VELOCITY)
    path = save_model(tmp_path / "m.h5", model)
    loaded, _ = load_model(path)
    assert isinstance(loaded, ConstraintInStretches)
    assert np.array_equal(loaded.A_, model.model_.A_) and loaded.stretches_ == model.model_.stretches_
    assert np.array_equal(loaded.projection(train.X, groups=train.demo, t=train.t),
                          model.projection(train.X, groups=train.demo, t=train.t))
    with pytest.raises(InputError, match="not seen"):
        loaded.projection(new.X, groups=new.demo, t=new.t)
    # new recordings: the same row, their own stretches classified by the motion along it (said so)
    applied = applied_on(loaded, new, new.U, new_data=True)
    N, note = projection_on(applied, new), applied.note
    assert applied.rule.rule == "stretches classified" and applied.rule.keeps == ("rows", "k", "block")
    assert "holds in stretches" in note and "free motion elsewhere" in note
    assert (np.abs(N - new.true_projection()).max((1, 2)) < 0.05).mean() > 0.9


def test_a_saved_surface_in_phases_finds_the_phases_of_new_demonstrations(tmp_path):
    d = sim.arm_wipe(n_demos=8, seed=0)
    train, new = d.subset(d.demo < 6), d.subset(d.demo >= 6)
    model = fit_auto(train)
    path = save_model(tmp_path / "m.h5", model)
    loaded, _ = load_model(path)
    assert isinstance(loaded, ManifoldInPhases)
    assert np.array_equal(loaded.projection(train.X, groups=train.demo, t=train.t),
                          model.projection(train.X, groups=train.demo, t=train.t))
    applied = applied_on(loaded, new, new.U, new_data=True)
    assert applied.rule.rule == "phases found again" and applied.rule.keeps == ("levels", "k")
    N = projection_on(applied, new)
    assert (np.abs(N - new.true_projection()).max((1, 2)) < 0.05).mean() > 0.9
    with h5py.File(path, "r+") as f:  # a spread of the wrong length is refused on load
        del f["arrays/spread_"]
        f["arrays"].create_dataset("spread_", data=np.ones(2))
    with pytest.raises(InputError, match="spread_"):
        load_model(path)


def test_damaged_blocks_are_refused(tmp_path, wipe_model):
    path = save_model(tmp_path / "m.h5", wipe_model)
    with h5py.File(path, "r+") as f:
        blocks = f["arrays/blocks_"][()]
        blocks[0, 2] = 2
        del f["arrays/blocks_"]
        f["arrays"].create_dataset("blocks_", data=blocks)
    with pytest.raises(InputError, match="blocks_"):
        load_model(path)


def test_fill_still_and_stretch_ranges_by_hand():
    holds = np.array([False, True, False, False, True, True, False])
    moving = np.array([True, True, False, True, True, False, False])
    demo = np.array([0, 0, 0, 0, 1, 1, 1])
    # block 2 (still) takes block 1's label; blocks 5, 6 (still) take block 4's; block 3 moves
    assert fill_list(holds, moving, demo) == [False, True, True, False, True, True, True]
    table = np.array([[0, 0, 0], [0, 1, 1], [0, 2, 1], [0, 3, 0], [1, 0, 1], [1, 1, 1], [1, 3, 1]])
    assert st.stretches(table, 0.5) == [[0, 0.5, 1.5], [1, 0.0, 1.0], [1, 1.5, 2.0]]
    # a demonstration whose first blocks are still takes its first moving block's label
    assert fill_list(np.array([False, True]), np.array([False, True]), np.array([0, 0])) == [True, True]


def fill_list(holds, moving, demo) -> list[bool]:
    return [bool(v) for v in st.fill_still(holds, moving, demo)]


def test_quiet_rule_by_hand():
    C = np.zeros((3, 2, 2))
    C[0] = np.diag([1.0, 1e-6])  # moves along x, along y at the noise level
    C[1] = np.diag([1.0, 5e-4])  # along y: far above the noise, 5e-4 of the typical motion
    C[2] = np.diag([1.0, 0.01])  # along y: a share of the motion
    blocks = st.Blocks(C, np.ones(3, int), np.ones(3, bool), np.zeros(3, int), np.zeros(3, int),
                       np.zeros((3, 2)), typical=1.0, noise=np.diag([1e-7, 1e-6]))
    assert st.quiet(blocks, np.array([[0.0, 1.0]])).tolist() == [True, True, False]
    assert st.quiet(blocks, np.array([[1.0, 0.0]])).tolist() == [False, False, False]
    # with 10× the noise along y, block 2's motion along y (0.01 = 10 σ²) is at the noise level
    blocks.noise = np.diag([1e-7, 1e-3])
    assert st.quiet(blocks, np.array([[0.0, 1.0]])).tolist() == [True, True, True]


def test_noise_covariance_of_correlated_white_noise_by_hand():
    rng = np.random.default_rng(0)
    L = np.array([[1.0, 0.0, 0.0], [0.5, 1.0, 0.0], [0.0, -0.3, 0.5]]) * 1e-3
    U = rng.normal(size=(40_000, 3)) @ L.T  # recorded actions: white noise of covariance L Lᵀ
    data = nr.Sample.of(np.zeros((len(U), 1)), U, None, np.arange(len(U)) * 0.01, False)
    S = st.noise_covariance(data)
    assert np.allclose(S, L @ L.T, atol=0.05 * 1e-6)


def test_needs_the_sample_times():
    d = sim.arm_wipe(n_demos=2, seed=0)
    with pytest.raises(InputError, match="sample times"):
        ConstraintInStretches().fit(d.X, d.U, groups=d.demo)


def test_the_rows_of_a_curved_surface_in_phases_are_described_where_it_holds(wipe):
    """A bowl's rows turn with the state: the report reads them at a sample where it holds, with
    its demonstration (where it holds is found on the whole of it), not at one sample alone."""
    from ccl_cli.app.views import describe_constraint

    model = ManifoldInPhases(family="sphere", n_constraints=1).fit(wipe.X, wipe.U, groups=wipe.demo)
    shown = describe_constraint(model, wipe)
    assert shown is not None and shown["at"].startswith("state of sample")
    i = int(shown["at"].split()[3])
    assert model.holds(wipe.X, groups=wipe.demo)[i]
    assert subspace_angle(np.array(shown["rows"]), np.atleast_2d(wipe.metadata["normal"])) < 5.0


def wipes_2d(n_demos: int = 5, seed: int = 0, rate: float = 100.0):
    """A hand wiping along a line in the plane (tilted 0.1 rad): an approach from above (free),
    strokes back and forth on the line, a retract (free); positions with 0.2 mm noise."""
    from ccl_cli.dataset import Demonstrations

    rng = np.random.default_rng(seed)
    turn = np.array([[np.cos(0.1), -np.sin(0.1)], [np.sin(0.1), np.cos(0.1)]])
    X, demo = [], []
    for k in range(n_demos):
        x0 = rng.uniform(-0.1, 0.1)
        approach = np.column_stack([np.full(150, x0), np.linspace(0.3, 0.0, 150)])
        strokes = np.column_stack([x0 + 0.08 * np.sin(np.linspace(0, 8 * np.pi, 800)), np.zeros(800)])
        retract = np.column_stack([strokes[-1, 0] + np.linspace(0, 0.1, 150), np.linspace(0.0, 0.3, 150)])
        P = np.vstack([approach, strokes, retract]) + rng.normal(scale=2e-4, size=(1100, 2))
        X.append(P @ turn.T)
        demo.append(np.full(1100, k))
    X = np.vstack(X)
    t = np.tile(np.arange(1100) / rate, n_demos)
    return Demonstrations(X=X, U=np.gradient(X, axis=0) * rate, demo=np.concatenate(demo), t=t)


def test_a_constraint_in_phases_draws_no_field_on_a_grid():
    """The learn-a figure of a 2-D model drew Ñ's null direction on a grid of states; a grid is not
    a recording, and a model in phases found its phases in the grid's raster order: the field
    showed (1, 0) — Ñ = I's first column — at every grid state, whatever the line (0.1 rad here).
    Only a model whose Ã(x) is fixed by the state alone draws a field there."""
    from ccl_cli.app.stages import StageResult
    from ccl_cli.app.views import stage_views
    from ccl_cli.learn.constraint import StateIndependentConstraint

    d = wipes_2d()
    phases = ManifoldInPhases(family="linear", n_constraints=1).fit(d.X, d.U, groups=d.demo)
    assert phases.new_data_rule.rule == "phases found again" and 0.6 < phases.share_ < 0.8
    assert subspace_angle(phases.constant_rows(), np.array([[-np.sin(0.1), np.cos(0.1)]])) < 1.0

    def field(model):
        views = stage_views(StageResult("learn-a", "m", model), d, "train", d, False)
        return next(v for v in views if v.kind == "field").args["field"]

    assert field(phases) is None  # the arrows at the recording's states only
    plain = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    grid = field(plain)
    along = np.abs(grid["F"] / np.linalg.norm(grid["F"], axis=1, keepdims=True) @ plain.A_[0])
    assert grid["F"].shape[1] == 2 and along.max() < 1e-6  # Ñ's direction: orthogonal to its row
