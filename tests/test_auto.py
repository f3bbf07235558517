"""learn-a's ``auto`` (ccl_cli/learn/constraint/auto.py), the per-window constraint
(windows.py), "no constraint" (none.py) and the folds inside windows: on the simulations of
issue 17, against their ground truth. The 20-seed bars are in benchmarks/bench_auto.py."""

import json

import h5py
import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.dataset import Derivative
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn import model_selection as S
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.constraint import (
    AutoConstraint,
    NoConstraint,
    PerSegment,
    PerWindow,
    StateIndependentConstraint,
)
from ccl_cli.learn.constraint.auto import CANDIDATES
from ccl_cli.learn.constraint.windows import window_index
from ccl_cli.metrics import subspace_angle
from ccl_cli.models import load_model, save_model


def ccl(capsys, *args) -> dict:
    """Run the command line in this process; its --json summary."""
    capsys.readouterr()
    assert main([str(a) for a in args]) == 0
    out = capsys.readouterr().out
    return json.loads(out) if out.strip() else {}


#: learn-a's candidates but the states' geometry: the velocities alone decide (the path taken when the
#: actions are not the states' derivative, or the states show no constraint).
VELOCITY = [c for c in CANDIDATES if c != "manifold"]


def fit_auto(d, **kw) -> AutoConstraint:
    derivative = d.metadata.get("derivative", False)
    return AutoConstraint(**kw).fit(d.X, d.U, groups=d.demo, t=d.t, derivative=derivative)


def row_of(model: AutoConstraint, name: str) -> dict:
    return next(r for r in model.selection_["candidates"] if r["class"] == name)


# -- the answers on the simulated recordings -------------------------------------------------------
@pytest.mark.parametrize("make", [lambda: sim.free_reach(seed=3), lambda: sim.flow2d(seed=4)],
                         ids=["free_reach", "flow2d"])
def test_free_motion_has_no_constraint(make):
    d = make()
    model = fit_auto(d)
    assert model.n_constraints_ == 0 and model.selection_["chosen"] == "none"
    assert isinstance(model.model_, NoConstraint)
    identity = np.broadcast_to(np.eye(d.n_action), (d.n_samples, d.n_action, d.n_action))
    assert np.array_equal(model.projection(d.X, groups=d.demo, t=d.t), identity)
    assert model.selection_["reason"].startswith("no constraint")
    # every global candidate saw the motion along its first row at least 10× the noise, held out;
    # the constraint in stretches found its row quiet in too small a share of the held-out time
    for r in model.selection_["candidates"]:
        if r["noise_ratio"] and r["class"] != "stretches":
            assert r["k"] == 0 and r["noise_ratio"][0] > 10
    stretches = next(r for r in model.selection_["candidates"] if r["class"] == "stretches")
    assert stretches["k"] == 0 and stretches["time_share"] < stretches["min_time_share"]
    # today's default finds a constraint here
    assert StateIndependentConstraint().fit(d.X, d.U).n_constraints_ == 1


def test_times_from_an_assumed_rate_cut_nothing_in_seconds(tmp_path, capsys):
    """Stamps made from data.time.rate: the candidates that cut the recording in seconds are not
    tried (their windows would hold other samples at another assumed rate), and the text matrix's
    Demonstrations say their times were assumed; a recording with stamps tries them."""
    from ccl_cli.io import load_demonstrations

    d = sim.tracker_tilt(seed=1)
    model = fit_auto(d, candidates=VELOCITY, rate_assumed=True)
    for name in ("per_window", "per_segment", "stretches"):
        assert "assumed rate" in row_of(model, name)["reason"]
    assert model.n_constraints_ == 1 and model.selection_["chosen"] not in ("per_window", "per_segment")
    assert row_of(fit_auto(d, candidates=VELOCITY), "per_window")["k"] is not None
    path = tmp_path / "tilt.txt"
    np.savetxt(path, d.X[d.demo == d.demo[0]])
    paced = load_demonstrations({"files": [str(path)], "state": {"columns": [0, 1, 2]}, "time": {"rate": 30}})
    assert paced.rate_assumed and not d.rate_assumed
    config = tmp_path / "c.yaml"
    config.write_text(json.dumps({"data": {"files": [str(path)], "state": {"columns": [0, 1, 2]},
                                           "time": {"rate": 30}},
                                  "learn-a": {"candidates": ["nhat", "per_window"]}}))
    ccl(capsys, "learn-a", "-c", config, "-o", tmp_path / "out", "--json", "-q")
    metrics = json.loads((tmp_path / "out" / "metrics.json").read_text())["learn-a"]
    rows = {r["class"]: r for r in metrics["selection"]["candidates"]}
    assert "assumed rate" in rows["per_window"]["reason"]


def test_a_plane_is_one_constant_constraint():
    d = sim.tracker_plane(duration=40.0, seed=5)
    model = fit_auto(d)  # the states show the plane: one constant A, its rows from the velocities
    assert model.n_constraints_ == 1 and model.selection_["chosen"] == "nhat"
    assert model.selection_["decided_by"] == "states" and subspace_angle(model.A_, d.truth["A"]) < 1.5
    plane = next(r for r in model.selection_["geometry"]["models"] if r["chosen"])
    assert (plane["k"], plane["scope"], plane["basis"]) == (1, "global", "linear")
    assert plane["drift"][0] < 0.05
    assert all(not r["holds"] for r in model.selection_["geometry"]["models"] if r["k"] == 2)
    model = fit_auto(d, candidates=VELOCITY)  # the velocities alone agree
    assert model.n_constraints_ == 1 and model.selection_["chosen"] == "nhat"
    assert subspace_angle(model.A_, d.truth["A"]) < 1.5
    nhat = row_of(model, "nhat")
    assert nhat["chosen"] and 0.5 < nhat["noise_ratio"][0] < 2 and nhat["noise_ratio"][1] > 20


def test_a_tilting_board_gets_one_constraint_per_stretch():
    """A board turning all the time. By default the states show one surface and parsimony keeps
    one plane (as on the real Trakstar recording of a tilting table, whose truth is its one plane:
    docs/auto.md); the velocities alone take one constant constraint per window or per segment
    (which of the two is within one SE of the other), nearer the board's normals than one plane."""
    d = sim.tracker_tilt(seed=1)
    default = fit_auto(d)
    assert default.n_constraints_ == 1 and default.selection_["chosen"] == "nhat"
    model = fit_auto(d, candidates=VELOCITY)
    assert model.n_constraints_ == 1 and model.selection_["chosen"] in ("per_segment", "per_window")
    assert isinstance(model.model_, PerWindow)
    held = model.heldout_
    assert held["mean"] < 0.03 and "inside every 4-s window" in held["folds"]
    assert held["mean"] < row_of(model, "nhat")["heldout_error"] - row_of(model, "nhat")["se"]
    A = model.constraint(d.X, groups=d.demo, t=d.t)
    angles = [subspace_angle(A[i], d.truth["A"][i]) for i in range(0, d.n_samples, 25)]
    plane = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    one = [subspace_angle(plane.A_, d.truth["A"][i]) for i in range(0, d.n_samples, 25)]
    assert np.median(angles) < 5 and np.median(angles) < 0.6 * np.median(one)


def test_a_bowl_gets_a_state_dependent_or_per_window_constraint():
    d = sim.tracker_sphere(duration=60.0, seed=2)
    model = fit_auto(d)
    assert model.n_constraints_ == 1
    assert model.selection_["chosen"] == "manifold" and model.chosen_.family == "sphere"  # the bowl itself
    velocity = fit_auto(d, candidates=VELOCITY)
    assert velocity.selection_["chosen"] in ("alpha_linear", "alpha", "per_window")
    assert velocity.heldout_["mean"] < 0.03
    assert row_of(velocity, "nhat")["k"] != 2  # the constant model does not take the curvature for a 2nd row
    rows = model.constraint(d.X[::50], groups=d.demo[::50], t=d.t[::50])
    assert np.median([subspace_angle(rows[i], d.truth["A"][j]) for i, j in
                      enumerate(range(0, d.n_samples, 50))]) < 3


def test_two_constant_rows_of_the_arm_on_held_out_demonstrations():
    d = sim.arm7(rows=(0, 1), seed=3)
    hold = S.holdout_split(d.demo, 0.3, 0)
    tr, te = d.subset(hold.train), d.subset(hold.test)
    for model in (fit_auto(tr), fit_auto(tr, candidates=VELOCITY)):  # the states, then the velocities alone
        assert model.n_constraints_ == 2
        assert np.abs(model.projection(te.X, groups=te.demo, t=te.t) - te.true_projection()).max() <= 1e-2
    per_demo = row_of(model, "per_demo")
    assert per_demo["k"] <= 2  # directions one short demonstration did not take are not constraints
    assert row_of(model, "alpha")["reason"].startswith("not tried: 7 state dimensions")


def test_lambda_finds_both_rows_of_the_jacobian_constraint():
    d = sim.arm7(rows=(0, 1), constraint="jacobian", seed=4)
    model = fit_auto(d, features={"arm": "arm7", "rows": [0, 1, 2]})
    assert model.n_constraints_ == 2 and model.selection_["chosen"] == "lambda"
    assert row_of(model, "nhat")["k"] < 2  # a constant A does not explain the arm's motion


@pytest.mark.parametrize("seed", [0, 5, 11])
def test_lambda_default_rule_is_the_noise_test_on_its_rows(seed):
    """Explicit ``method: lambda``: its default rule reads the noise of the trajectories (the
    ratio rule finds both Jacobian rows in 3 of seeds 0–19, noise in 20: docs/auto.md)."""
    from ccl_cli.learn.constraint import KnownFeatureConstraint
    from ccl_cli.learn.constraint.noise_rank import Sample, row_evidence

    d = sim.arm7(rows=(0, 1), constraint="jacobian", seed=seed)
    features = {"arm": "arm7", "rows": [0, 1, 2]}
    model = KnownFeatureConstraint(features=features).fit(d.X, d.U, groups=d.demo, t=d.t, derivative=False)
    assert model.n_constraints_ == 2 and model.selection_["rule"] == "noise"
    # the figures it read: the motion along each learnt row against that row's noise, by hand
    ev = row_evidence(d.U, model.constraint(d.X), d.demo, d.t, recorded=True)
    assert np.allclose(model.selection_["values"], ev.ratio) and max(ev.ratio) < 10
    assert np.abs(model.projection(d.X) - d.true_projection()).max() < 5e-2
    # ratio (kept as an option) reads the nmse sequence instead
    ratio = KnownFeatureConstraint(features=features, selection="ratio").fit(d.X, d.U, groups=d.demo)
    assert ratio.selection_["rule"] == "ratio" and ratio.selection_["values"] == ratio.nmse_
    assert Sample.of(d.X, d.U, None, d.t, {"window": 9}).derived == Derivative(True, 9, 2)  # X has q columns


# -- the evidence, by hand -------------------------------------------------------------------------
def test_nhat_held_out_rows_and_npoe_by_hand():
    """nhat's held-out NPOE in the table is the NPOE of the smallest eigenvector of each
    training fold's Σ u uᵀ on its test fold (folds of make_folds), averaged over folds."""
    d = sim.tracker_plane(duration=30.0, seed=1)
    model = fit_auto(d, candidates=["none", "nhat"])
    folds = S.make_folds(d.demo, d.n_samples, 5, 0, d.derivative.window)
    errors = []
    for train, test in folds.pairs:
        a = np.linalg.eigh(d.U[train].T @ d.U[train])[1][:, 0]
        Ut = d.U[test]
        errors.append(np.mean((Ut @ a) ** 2) / np.var(Ut, axis=0, ddof=1).sum())
    nhat = row_of(model, "nhat")
    assert nhat["heldout_error"] == pytest.approx(np.mean(errors), rel=1e-9)
    assert nhat["se"] == pytest.approx(np.std(errors, ddof=1) / np.sqrt(5), rel=1e-9)
    assert model.heldout_["per_fold"] == pytest.approx(errors, rel=1e-9)


def test_the_table_says_why_for_every_candidate():
    d = sim.tracker_tilt(seed=0, duration=36.0)
    model = fit_auto(d, candidates=VELOCITY)
    rows = model.selection_["candidates"]
    assert [r["class"] for r in rows][:2] == ["none", "nhat"]
    assert sum(r["chosen"] for r in rows) == 1
    keys = {"class", "model", "k", "error", "heldout_error", "se", "noise_ratio", "share", "folds", "chosen",
            "reason"}
    assert all(keys <= set(r) and r["reason"] for r in rows)
    not_tried = {r["class"] for r in rows if r["reason"].startswith("not tried")}
    assert not_tried >= {"per_demo", "lambda", "linear"}
    json.dumps(model.selection_)  # the report and metrics.json can hold it


def test_the_same_data_give_the_same_model():
    d = sim.tracker_sphere(duration=30.0, seed=0)
    a, b = fit_auto(d), fit_auto(d)
    assert a.selection_ == b.selection_
    assert np.array_equal(a.projection(d.X, groups=d.demo, t=d.t), b.projection(d.X, groups=d.demo, t=d.t))


def test_fixed_number_of_constraints_and_unknown_candidates():
    d = sim.tracker_plane(duration=30.0, seed=0)
    model = fit_auto(d, n_constraints=2, candidates=["nhat", "per_window"])
    assert model.n_constraints_ == 2 and model.model_.n_constraints_ == 2
    with pytest.raises(ConfigError, match="unknown candidate 'alfa'"):
        fit_auto(d, candidates=["alfa"])


def test_too_few_samples_to_cross_validate_fall_back_to_nhat():
    d = sim.tracker_plane(duration=1.0, seed=0)
    model = fit_auto(d)
    assert "not cross-validated" in model.selection_["reason"] and model.n_constraints_ in (0, 1)


# -- folds inside windows, the per-window model ------------------------------------------------------
def test_inner_folds_hold_out_each_sample_once_in_blocks_inside_every_window():
    t = np.arange(600) * 0.02
    demo = np.repeat([0, 1], 300)
    seg, table = window_index(demo, t, 2.0, 600)
    assert table.tolist() == [[0, 0], [0, 1], [0, 2], [1, 3], [1, 4], [1, 5]]  # ⌊t / 2 s⌋, per demonstration
    folds = S.inner_folds(seg, 5, 3)
    held = np.concatenate([test for _, test in folds.pairs])
    assert np.array_equal(np.sort(held), np.arange(600))
    for train, test in folds.pairs:
        for s in np.unique(seg):
            inside = test[seg[test] == s]
            assert len(inside) == 20 and np.all(np.diff(inside) == 1)  # one block of 20 per window
        dist = np.abs(train[:, None] - test[None, :]).min(1)
        assert dist.min() > 3  # guard gaps


def test_per_window_rows_are_each_windows_eigenvectors_without_shrinkage():
    d = sim.tracker_tilt(seed=2, duration=24.0)
    model = PerWindow(window=6.0, n_constraints=1, shrinkage=0.0).fit(d.X, d.U, groups=d.demo, t=d.t)
    assert model.windows_.tolist() == [[0, j] for j in range(4)]
    for j in range(4):
        inside = (d.t >= 6.0 * j) & (d.t < 6.0 * (j + 1))
        a = np.linalg.eigh(d.U[inside].T @ d.U[inside])[1][:, 0]
        assert subspace_angle(model.A_[j], a[None]) < 1e-6
    # a sample after the last window takes the nearest (last) one
    late = model.constraint(d.X[:1], groups=np.array([0]), t=np.array([40.0]))
    assert np.array_equal(late[0], model.A_[3])
    with pytest.raises(InputError, match="needs the sample times"):
        model.projection(d.X[:3], groups=d.demo[:3])
    with pytest.raises(InputError, match="demonstration 7 was not seen"):
        model.projection(d.X[:3], groups=np.full(3, 7), t=d.t[:3])


def test_per_window_held_out_figure_is_its_own_refit_by_hand():
    d = sim.tracker_tilt(seed=3, duration=30.0)
    deriv = d.derivative
    model = PerWindow(n_constraints=1).fit(d.X, d.U, groups=d.demo, t=d.t, derivative=deriv)
    seg, _ = window_index(d.demo, d.t, 4.0, d.n_samples)
    errors = []
    for train, test in S.inner_folds(seg, 5, d.derivative.window).pairs:
        twin = PerWindow(n_constraints=1, heldout=False).fit(d.X[train], d.U[train], groups=d.demo[train],
                                                             t=d.t[train])
        errors.append(npoe_error(twin.projection(d.X[test], groups=d.demo[test], t=d.t[test]), d.U[test]))
    assert model.heldout_["per_fold"] == pytest.approx(errors, rel=1e-12)


def test_per_window_rank_by_the_noise_rule():
    d = sim.tracker_tilt(seed=4)
    assert PerWindow().fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative
                           ).n_constraints_ == 1
    free = sim.free_reach(seed=1)
    assert PerWindow().fit(free.X, free.U, groups=free.demo, t=free.t,
                           derivative=free.derivative).n_constraints_ == 0


# -- saving, loading, using on new recordings ------------------------------------------------------------
def test_auto_saves_the_model_it_chose_with_its_table(tmp_path):
    d = sim.tracker_tilt(seed=1, duration=30.0)
    model = fit_auto(d, candidates=["none", "nhat", "per_window"])  # per_segment: test_segments.py
    path = save_model(tmp_path / "m.h5", model)
    again, info = load_model(path)
    assert info["method"] == "per_window" and type(again) is PerWindow
    assert again.window_ == 4.0 and again.heldout_ == model.heldout_
    assert again.selection_["candidates"] == model.selection_["candidates"]
    at = {"groups": d.demo, "t": d.t}
    assert np.array_equal(again.projection(d.X, **at), model.projection(d.X, **at))
    with h5py.File(path, "r+") as f:  # a window table that is not integers is refused
        table = f["arrays/windows_"][()].astype(float)
        table[0, 1] = 0.5
        del f["arrays/windows_"]
        f["arrays/windows_"] = table
    with pytest.raises(InputError, match="windows_"):
        load_model(path)


def test_no_constraint_saves_and_loads(tmp_path):
    d = sim.flow2d(seed=0)
    path = save_model(tmp_path / "none.h5", fit_auto(d))
    again, info = load_model(path)
    assert info["method"] == "none" and again.n_constraints_ == 0
    assert np.array_equal(again.projection(d.X), np.broadcast_to(np.eye(2), (d.n_samples, 2, 2)))


def test_cli_default_is_auto_and_per_window_models_are_refitted_on_new_recordings(tmp_path, capsys):
    for seed in (0, 1):
        ccl(capsys, "simulate", "tracker_tilt", "-o", tmp_path / f"tilt{seed}.h5", "--seed", seed, "-q")
    res = ccl(capsys, "learn-a", tmp_path / "tilt0.h5", "-o", tmp_path / "default", "--json", "-q")
    assert res["stages"]["learn-a"]["method"] == "auto" and res["stages"]["learn-a"]["n_constraints"] == 1
    # the velocities alone (auto without the states' geometry) take one constant A per stretch
    cfg = tmp_path / "velocity.yaml"
    cfg.write_text("learn-a:\n  method: auto\n  candidates: [" + ", ".join(VELOCITY) + "]\n")
    out = tmp_path / "a"
    res = ccl(capsys, "learn-a", tmp_path / "tilt0.h5", "-c", cfg, "-o", out, "--json", "-q")
    assert res["stages"]["learn-a"]["method"] == "auto" and res["stages"]["learn-a"]["n_constraints"] == 1
    metrics = json.loads((out / "metrics.json").read_text())["learn-a"]
    chosen = metrics["selection"]["chosen"]
    assert chosen in ("per_segment", "per_window") and len(metrics["selection"]["candidates"]) == 10
    said = "one constant A per segment" if chosen == "per_segment" else "one constant A per 4-s window"
    assert said in (out / "report.md").read_text()
    ev = ccl(capsys, "evaluate", out / "model.h5", tmp_path / "tilt1.h5", "--json", "-q")
    assert "fitted again on these data" in ev["note"] and ev["metrics"]["NPOE"] < 0.02
    pred = ccl(capsys, "predict", out / "model.h5", tmp_path / "tilt1.h5", "-o", tmp_path / "p.h5", "--json",
               "-q")
    assert "training figures" in pred["note"]
    with h5py.File(tmp_path / "p.h5") as f:
        N = f["N"][()]
    from ccl_cli.io import read_demonstrations

    d1, _ = read_demonstrations(tmp_path / "tilt1.h5")
    saved, _ = load_model(out / "model.h5")
    refit = saved.same_kind().fit(d1.X, d1.U, groups=d1.demo, t=d1.t)
    assert type(refit) is {"per_segment": PerSegment, "per_window": PerWindow}[chosen]
    assert np.array_equal(N, refit.projection(d1.X, groups=d1.demo, t=d1.t))


def test_cli_free_reach_says_no_constraint(tmp_path, capsys):
    ccl(capsys, "simulate", "free_reach", "-o", tmp_path / "r.h5", "-q")
    res = ccl(capsys, "learn-a", tmp_path / "r.h5", "-o", tmp_path / "a", "--json", "-q")
    assert res["stages"]["learn-a"]["n_constraints"] == 0
    assert "Constraints: **0** (rule: auto; no constraint" in (tmp_path / "a" / "report.md").read_text()


def test_auto_is_the_default_and_explicit_methods_are_unchanged():
    from ccl_cli import spec as S_
    from ccl_cli.app.stages import make_constraint

    assert S_.DEFAULT_CONSTRAINT_METHOD == "auto"
    section = S_.stage_models()["learn-a"]
    assert isinstance(make_constraint(section(), 0), AutoConstraint)
    assert type(make_constraint(section(method="nhat"), 0)) is StateIndependentConstraint
    per_demo = make_constraint(section(per_demo=True), 0)
    assert isinstance(per_demo, PerWindow) and per_demo.window is None


def test_unknown_provenance_takes_the_larger_noise_estimate():
    """Velocities derived from positions but not said to be: the white-noise estimate of the
    smoothed velocities is far too small; with recorded=False the positions' noise through
    the readers' default filter is used, which is what the derivative says."""
    from ccl_cli.learn.constraint import noise_rank as nr

    d = sim.tracker_plane(duration=30.0, seed=0)
    rows = np.linalg.eigh(d.U.T @ d.U)[1].T[:2]
    told = nr.row_evidence(d.U, rows, d.demo, d.t, d.X, d.derivative)
    recorded = nr.row_evidence(d.U, rows, d.demo, d.t, d.X)
    unknown = nr.row_evidence(d.U, rows, d.demo, d.t, d.X, recorded=False)
    assert np.allclose(unknown.noise, told.noise, rtol=1e-12)
    assert np.all(recorded.noise < 0.3 * told.noise)
