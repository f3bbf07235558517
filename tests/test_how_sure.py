"""How sure learn-a is (issue 30 item 7): each learnt row's cone over held-out folds and the
evidence for k − 1 and k + 1 (ccl_cli/learn/constraint/sure.py), in report.md, metrics.json and
``ccl inspect MODEL``; and the figures that explain the choice (issue 29 item 5, issue 30 item 3):
the count figure's bars and limits are the selection's numbers, the phases figure marks where the
constraint holds."""

from __future__ import annotations

import json

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.app.views import phases
from ccl_cli.cli import main
from ccl_cli.io import write_demonstrations
from ccl_cli.learn.constraint import AutoConstraint, sure
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.render import count, figures


def rotate(v: np.ndarray, axis: np.ndarray, deg: float) -> np.ndarray:
    """v turned about the unit ``axis`` by ``deg`` degrees (Rodrigues)."""
    a = np.radians(deg)
    return v * np.cos(a) + np.cross(axis, v) * np.sin(a) + axis * (axis @ v) * (1 - np.cos(a))


def fit(d, **kw) -> AutoConstraint:
    return AutoConstraint(**kw).fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative)


def test_angles_of_rows_from_held_out_spans_by_hand():
    e1, e2, e3 = np.eye(3)
    # one row 7° off: its angle and the largest principal angle are both 7°
    final = np.array([[e1]])
    held = np.array([[rotate(e1, e3, 7.0)]])
    per_row, largest, ok = sure.angles(final, held)
    assert per_row[0, 0] == pytest.approx(7.0) and largest[0] == pytest.approx(7.0) and ok.all()
    # two rows: the held-out span holds row 1 exactly and row 2 turned 20° out of the plane
    final = np.array([[e1, e2]])
    held = np.array([[e1, rotate(e2, e1, 20.0)]])
    per_row, largest, _ = sure.angles(final, held)
    assert per_row[0] == pytest.approx([0.0, 20.0], abs=1e-9) and largest[0] == pytest.approx(20.0)
    # the same span in other rows (a rotation within it) is no angle at all; rows of zeros are left out
    held = np.array([[(e1 + e2) / np.sqrt(2), (e1 - e2) / np.sqrt(2)], [np.zeros(3), e2]])
    per_row, largest, ok = sure.angles(np.array([[e1, e2], [e1, e2]]), held)
    assert ok.tolist() == [True, False] and per_row[0] == pytest.approx([0.0, 0.0], abs=1e-7)
    # the cone: median and 90th percentile over the samples
    tilts = np.arange(1.0, 11.0)  # 1 … 10°
    found = sure.cone(np.tile(e1, (10, 1, 1)), np.array([[rotate(e1, e3, a)] for a in tilts]), "by hand")
    assert found["rows"][0]["median_deg"] == pytest.approx(5.5)
    assert found["rows"][0]["p90_deg"] == pytest.approx(np.percentile(tilts, 90))
    assert found["samples"] == 10 and found["over"] == "by hand"


def test_row_limits_are_the_rule_noise_rank_applies():
    limit, share = nr.row_limits(np.array([3.0, 50.0, 0.2]), share_rows=1)
    assert limit.tolist() == [10.0, 6.0, 6.0]  # rows after the first: min(MARGIN, RATIO · max(r1, 1))
    assert share[0] == nr.SHARE and np.isneginf(share[1:]).all()
    limit, _ = nr.row_limits(np.array([0.1, 1.5]))
    assert limit.tolist() == [10.0, 2.0]  # RATIO · max(r1, 1) with r1 < 1
    ev = nr.RowEvidence(energy=np.array([3.0, 5.9, 6.1]), noise=np.ones(3), share=np.array([0.5, 0.3, 0.2]),
                        snr=100.0)
    assert nr.noise_rank(ev, 3).n_constraints == 2  # 5.9 ≤ 6 quiet, 6.1 > 6 moves


def test_a_plane_from_its_positions_row_cone_and_neighbours():
    d = sim.tracker_plane(duration=30.0, seed=1)
    model = fit(d)
    sel = model.selection_
    assert model.n_constraints_ == 1 and sel["decided_by"] == "states"
    json.dumps(sel)  # JSON: saved with the model, written to metrics.json
    cone = sel["sure"]["cone"]
    assert cone["samples"] == d.n_samples and "time blocks" in cone["over"]
    row = cone["rows"][0]
    assert 0 < row["median_deg"] <= row["p90_deg"] < 1.0  # a plane learnt from 30 s of tracing
    near = {e["k"]: e for e in sel["sure"]["neighbours"]}
    assert set(near) == {0, 1, 2}
    assert near[0]["rejected"] and near[0]["value"] <= near[0]["limit"]  # row 1 holds
    assert near[2]["rejected"] and near[2]["value"] > near[2]["limit"]  # no line or circle
    # the numbers are those of the geometry's table
    shapes = sel["geometry"]["models"]
    two = [m for m in shapes if m["k"] == 2]
    nearest = min(max(m["drift"]) / m["limit"] for m in two)
    assert near[2]["value"] / near[2]["limit"] == pytest.approx(nearest)


def test_velocity_candidates_rows_quiet_up_to_k_and_the_next_one_moving():
    d = sim.arm7(rows=(0, 1), n_demos=20, seed=2)
    model = fit(d, candidates=["nhat", "per_demo"])
    sel = model.selection_
    assert model.n_constraints_ == 2 and sel["chosen"] == "nhat"
    nhat = next(r for r in sel["candidates"] if r["class"] == "nhat")
    limit, share = nr.row_limits(np.array(nhat["noise_ratio"]), share_rows=nr.SHARE_ROWS)
    assert nhat["noise_limit"] == pytest.approx(limit.tolist())
    assert nhat["share_limit"][0] == nr.SHARE and all(v is None for v in nhat["share_limit"][1:])
    near = {e["k"]: e for e in sel["sure"]["neighbours"]}
    assert near[1]["rejected"] and near[1]["value"] == nhat["noise_ratio"][1] <= near[1]["limit"]
    assert near[3]["rejected"] and near[3]["value"] == nhat["noise_ratio"][2] > 100 * near[3]["limit"]
    # the cone: held-out nhat rows against the final ones, from the same held-out rows the rank read
    cone = sel["sure"]["cone"]
    assert cone["over"] == nhat["folds"] and len(cone["rows"]) == 2
    assert all(r["p90_deg"] < 2.0 for r in cone["rows"])


def test_no_constraint_says_what_speaks_against_one():
    d = sim.free_reach(n_demos=6, seed=1)
    sel = fit(d).selection_
    assert sel["n_constraints"] == 0 and sel["sure"]["cone"] is None and sel["sure"]["why"]
    (one,) = sel["sure"]["neighbours"]
    assert one["k"] == 1 and one["rejected"] and one["value"] > one["limit"]
    closest = min((r for r in sel["candidates"] if r.get("noise_ratio") and r["class"] != "stretches"),
                  key=lambda r: r["noise_ratio"][0])
    assert one["value"] == closest["noise_ratio"][0] and one["words"].startswith(closest["class"])
    assert "in stretches: held in" in one["words"]


def test_report_metrics_and_inspect_say_how_sure(tmp_path, capsys):
    path = write_demonstrations(tmp_path / "plane.h5", sim.tracker_plane(duration=30.0, seed=1), force=True)
    out = tmp_path / "out"
    assert main(["learn-a", str(path), "-o", str(out), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    metrics = json.loads((out / "metrics.json").read_text())["learn-a"]
    cone = metrics["selection"]["sure"]["cone"]
    assert summary["stages"]["learn-a"]["cone"] == cone
    report = (out / "report.md").read_text()
    assert "### How sure" in report
    assert f"| 1 | {cone['rows'][0]['median_deg']:.2g}° | {cone['rows'][0]['p90_deg']:.2g}° |" in report
    assert "- k = 0 (fewer): rejected — row 1 of" in report and "- k = 2 (more): rejected — " in report
    assert main(["inspect", str(out / "model.h5")]) == 0
    shown = capsys.readouterr().out
    assert f"cone:     row 1 {cone['rows'][0]['median_deg']:.2g}°" in shown
    assert "k = 0:    rejected: row 1 of" in shown
    assert "k = 2:    rejected: the best model with 2 rows" in shown


# -- figures -------------------------------------------------------------------------------------
def test_count_figure_of_the_states_geometry_draws_each_model_and_its_limit():
    d = sim.tracker_plane(duration=30.0, seed=1)
    sel = fit(d).selection_
    fig = count.selection_figure(sel, 3)
    ax = fig.axes[0]
    shapes = sel["geometry"]["models"]
    bars = [c for c in ax.collections if not hasattr(c, "get_segments")]  # one collection per rank k
    tops = [p.vertices[1, 1] for c in bars for p in c.get_paths()]
    floor = 1e-3 * min(m["limit"] for m in shapes)
    assert tops == pytest.approx([max(max(m["drift"]), floor) for m in sorted(shapes, key=lambda m: m["k"])])
    limits = [s[0][1] for c in ax.collections if hasattr(c, "get_segments") for s in c.get_segments()]
    assert limits == pytest.approx([m["limit"] for m in sorted(shapes, key=lambda m: m["k"])])
    chosen = [t.get_text() for t in ax.texts if t.get_color() == count.CHOSEN_COLOUR]
    assert chosen == ["k = 1"]


def test_count_figure_of_the_velocities_draws_ratios_shares_and_the_rule():
    d = sim.arm7(rows=(0, 1), n_demos=20, seed=2)
    sel = fit(d, candidates=["nhat", "per_demo"]).selection_
    fig = count.selection_figure(sel, 7)
    ratio_ax, share_ax = fig.axes
    nhat = next(r for r in sel["candidates"] if r["class"] == "nhat")
    line = next(ln for ln in ratio_ax.lines if ln.get_label().startswith("nhat"))
    assert line.get_ydata() == pytest.approx(nhat["noise_ratio"]) and "chosen" in line.get_label()
    (limits,) = [c for c in ratio_ax.collections if hasattr(c, "get_segments")]
    assert [s[0][1] for s in limits.get_segments()] == pytest.approx(nhat["noise_limit"])
    (share_limit,) = [c for c in share_ax.collections if hasattr(c, "get_segments")]
    assert [s[0][1] for s in share_limit.get_segments() if len(s)] == [nr.SHARE]  # row 1 only


@pytest.fixture(scope="module")
def wipe():
    return sim.arm_wipe(n_demos=6, seed=1)


def test_phases_where_the_constraint_holds_against_the_truth(wipe, tmp_path):
    model = fit(wipe)
    found = phases(model, wipe)
    truth = np.abs(wipe.true_projection() - np.eye(3)).max((1, 2)) > 0
    on = model.holds(wipe.X, groups=wipe.demo, t=wipe.t)
    assert found["share"] == pytest.approx(on.mean()) and (on == truth).mean() > 0.9
    for demo in found["demos"]:
        sel = wipe.demo == demo["demo"]
        t = wipe.t[sel] - wipe.t[sel][0]
        true_held = np.diff(t).mean() * truth[sel].sum()
        assert demo["held_s"] == pytest.approx(true_held, abs=1.0)  # blocks of 0.5 s
        assert demo["held_s"] == pytest.approx(sum(b - a for a, b in demo["spans"]))
    # the figure: one panel per demonstration, shaded where it holds
    from ccl_cli.app.views import phase_series

    data = phase_series(model, wipe, "t")
    fig = figures.phases_figure(**data)
    assert len(fig.axes) == wipe.n_demos
    assert np.array_equal(data["true_holds"], truth)


def test_a_run_on_a_whole_wipe_recording_reports_its_phases(wipe, tmp_path, capsys):
    path = write_demonstrations(tmp_path / "wipe.h5", wipe, force=True)
    out = tmp_path / "out"
    assert main(["learn-a", str(path), "-o", str(out), "-q"]) == 0
    metrics = json.loads((out / "metrics.json").read_text())["learn-a"]
    report = (out / "report.md").read_text()
    assert "### Phases" in report and "![learn-a: where the constraint holds over time]" in report
    first = metrics["phases"]["demos"][0]
    a, b = first["spans"][0]
    row = f"| {first['demo']} | {first['held_s']:.1f} | {first['duration_s']:.1f} | {a:.1f}–{b:.1f}"
    assert row in report
    assert (out / "plots" / "learn-a-phases.png").exists()
