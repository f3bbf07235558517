"""One constant constraint per segment, cut where the constraint changes (PerSegment)."""

import itertools
from dataclasses import replace

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.errors import InputError
from ccl_cli.learn.constraint import AutoConstraint, PerSegment, PerWindow, StateIndependentConstraint
from ccl_cli.learn.constraint.auto import CANDIDATES
from ccl_cli.learn.constraint.segments import cut, quietest_motion
from ccl_cli.metrics import subspace_angle
from ccl_cli.models import load_model, save_model


def angles_deg(model, d) -> np.ndarray:
    """Angle (°) between the learnt row and the true normal at every sample."""
    rows = model.constraint(d.X, groups=d.demo, t=d.t)[:, 0]
    true = d.truth_per_sample("A")[:, 0]
    cos = np.abs(np.einsum("ni,ni->n", rows, true)) / np.linalg.norm(true, axis=1)
    return np.degrees(np.arccos(np.clip(cos, -1.0, 1.0)))


def test_the_cuts_are_the_optimal_partition():
    """The dynamic programme against every partition of 7 blocks into segments of ≤ 4 blocks."""
    rng = np.random.default_rng(3)
    q, B, longest, beta = 3, 7, 4, 0.7
    U = rng.normal(size=(B, 5, q)) * rng.uniform(0.1, 2.0, size=(B, 1, q))
    S = np.einsum("bni,bnj->bij", U, U)
    counts = np.full(B, 5.0)
    prior = 0.05 * np.eye(q)

    def cost(spans):
        return sum(quietest_motion(S[i:j].sum(0) + (j - i) * 5.0 * prior) + beta for i, j in spans)

    best = np.inf
    for mask in itertools.product([0, 1], repeat=B - 1):  # a cut after block b where mask[b]
        edges = [0, *[b + 1 for b, m in enumerate(mask) if m], B]
        spans = list(zip(edges[:-1], edges[1:], strict=True))
        if all(j - i <= longest for i, j in spans):
            best = min(best, cost(spans))
    found = cut(S, counts, prior, beta, longest)
    assert found[0][0] == 0 and found[-1][1] == B
    assert all(a[1] == b[0] for a, b in zip(found, found[1:], strict=False))
    assert cost(found) == pytest.approx(best, rel=1e-12)


@pytest.mark.parametrize("seed", [0, 1, 2])
def test_a_board_tilting_in_steps_is_cut_at_its_steps(seed):
    """Steps every 6 s (by 0–28°): a cut within 1 s of most steps of more than 6° (a step about
    an axis along which the strokes run does not show in the motion), and rows nearer the true
    normals than fixed 4-s windows'."""
    d = sim.tracker_tilt(mode="steps", seed=seed)
    seg = PerSegment(n_constraints=1).fit(d.X, d.U, groups=d.demo, t=d.t)
    win = PerWindow(window=4.0, n_constraints=1).fit(d.X, d.U, groups=d.demo, t=d.t)
    cuts = seg.windows_[1:, 1] * seg.block
    windows = d.metadata["windows"]
    turn = [np.degrees(np.arccos(min(1.0, abs(float(np.dot(a["normal"], b["normal"]))))))
            for a, b in zip(windows, windows[1:], strict=False)]
    steps = np.array([b["t"][0] for b, deg in zip(windows[1:], turn, strict=True) if deg > 6.0])
    assert len(steps) >= 4
    near = np.abs(cuts[None, :] - steps[:, None]).min(1) <= 1.0
    assert near.mean() >= 0.7, (cuts, steps)
    a_seg, a_win = np.median(angles_deg(seg, d)), np.median(angles_deg(win, d))
    assert a_seg < 0.8 * a_win and a_seg < 3.0, (a_seg, a_win)
    assert seg.selection_["per"].startswith("segment") and seg.heldout_["mean"] < 0.03


def test_a_constant_plane_keeps_its_normal():
    """No change: segments as long as allowed (30 s), rows within 0.3° of nhat's."""
    d = sim.tracker_plane(duration=60.0, seed=0)
    seg = PerSegment(n_constraints=1).fit(d.X, d.U, groups=d.demo, t=d.t)
    one = StateIndependentConstraint(n_constraints=1).fit(d.X, d.U)
    assert len(seg.windows_) == 2
    assert max(subspace_angle(a, one.A_) for a in seg.A_) < 0.3


def test_auto_takes_the_segments_on_a_board_tilting_in_steps():
    d = sim.tracker_tilt(mode="steps", seed=1)
    velocity = [c for c in CANDIDATES if c != "manifold"]  # the velocities alone (tests/test_auto.py)
    model = AutoConstraint(candidates=velocity).fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative)
    assert model.selection_["chosen"] == "per_segment" and model.n_constraints_ == 1
    said = model.selection_["reason"]  # where the cuts are, in words
    first = model.model_.windows_[1, 1] * model.model_.block
    assert f"{len(model.model_.windows_)} segment(s); demo 0 cut at {first:.1f}, " in said
    assert np.median(angles_deg(model, d)) < 2.0
    rows = {r["class"]: r for r in model.selection_["candidates"]}
    assert rows["per_segment"]["heldout_error"] < rows["per_window"]["heldout_error"]


def test_saved_and_loaded_it_predicts_the_same_and_refits_on_a_new_recording(tmp_path):
    d = sim.tracker_tilt(mode="steps", seed=2)
    model = PerSegment().fit(d.X, d.U, groups=d.demo, t=d.t, derivative=d.derivative)
    save_model(tmp_path / "m.h5", model)
    back, _ = load_model(tmp_path / "m.h5")
    assert type(back) is PerSegment
    same = back.projection(d.X, groups=d.demo, t=d.t)
    assert np.array_equal(same, model.projection(d.X, groups=d.demo, t=d.t))
    other = sim.tracker_tilt(mode="steps", seed=5)
    other = replace(other, demo=other.demo + 7)  # a demonstration the model has not seen
    with pytest.raises(InputError, match="not seen"):
        back.projection(other.X, groups=other.demo, t=other.t)
    applied = back.applies_to(other.X, other.U, groups=other.demo, t=other.t, new_recording=False)
    refit, note = applied.model, applied.note
    assert type(refit) is PerSegment and "segment" in note and refit.n_constraints_ == back.n_constraints_
    assert applied.rule.rule == "rows fitted per stretch" and "k" in applied.rule.keeps
    assert np.median(angles_deg(refit, other)) < 3.0


def test_a_damaged_segment_table_is_refused(tmp_path):
    import h5py

    d = sim.tracker_tilt(mode="steps", seed=0)
    save_model(tmp_path / "m.h5", PerSegment(n_constraints=1).fit(d.X, d.U, groups=d.demo, t=d.t))
    with h5py.File(tmp_path / "m.h5", "r+") as f:
        table = f["arrays/windows_"][()]
        table[0, 2] = table[0, 1]  # an empty segment
        f["arrays/windows_"][...] = table
    with pytest.raises(InputError, match="windows_"):
        load_model(tmp_path / "m.h5")


def test_the_report_lists_each_segment_with_its_row_and_angle(tmp_path, capsys):
    """ccl learn-a --method per_segment on a recording of a board tilting in steps: report.md
    tabulates the segments (times, row 1, angle to the true normal), metrics.json too."""
    import json

    from ccl_cli.cli import main
    from ccl_cli.io.canonical import write_demonstrations

    d = sim.tracker_tilt(mode="steps", seed=1)
    write_demonstrations(tmp_path / "tilt.h5", d)
    assert main(["learn-a", str(tmp_path / "tilt.h5"), "--method", "per_segment", "-o", str(tmp_path / "a"),
                 "-q"]) == 0
    capsys.readouterr()
    report = (tmp_path / "a" / "report.md").read_text()
    assert "Row 1 of each segment (cut where the constraint changes)" in report
    assert "| demo | from (s) | to (s) | dx/dt | dy/dt | dz/dt | angle to truth |" in report
    shown = json.loads((tmp_path / "a" / "metrics.json").read_text())["learn-a"]["constraint"]["stretches"]
    model, _ = load_model(tmp_path / "a" / "model.h5")
    assert shown["count"] == len(model.windows_) and 1 <= len(shown["shown"]) <= 12
    first = shown["shown"][0]
    assert first["start_s"] == 0.0 and first["end_s"] == model.windows_[0, 2] * model.block
    assert f"| 0 | 0.0 | {first['end_s']:.1f} | " in report
    # the stretches' angles to the truth: most segments within a few degrees of the board
    assert np.median([s["angle_deg"] for s in shown["shown"]]) < 5.0
