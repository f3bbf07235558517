"""The constraint-count figure (learn-a-selection.png): each candidate with the evidence its rule
read and the rule's limit — checked through the numbers drawn, against the learner's selection_."""

from __future__ import annotations

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.learn.constraint import AutoConstraint, StateIndependentConstraint
from ccl_cli.render import count


def _dashes(ax) -> np.ndarray:
    """(x centre, y) of every horizontal dash (a limit) drawn on ``ax``: (n, 2)."""
    out = []
    for c in ax.collections:
        if hasattr(c, "get_segments"):
            out += [((s[0][0] + s[1][0]) / 2, s[0][1]) for s in c.get_segments() if len(s)]
    return np.array(out, dtype=float).reshape(-1, 2)


@pytest.fixture(scope="module")
def arm():
    return sim.arm7(rows=(0, 1), n_demos=12, seed=3)


@pytest.mark.parametrize("rule", ["ratio", "threshold", "cv"])
def test_a_learners_rule_draws_each_candidate_against_its_limit(arm, rule):
    """nhat on a 7-D arm with two true rows: every candidate row's value as drawn, the rule's
    limit as a dash over each row it applies to, rows 1 … k green, the chosen k ringed (the
    original's threshold rule counts 4 here: the figure shows why)."""
    model = StateIndependentConstraint(selection=rule).fit(arm.X, arm.U, groups=arm.demo)
    sel, k = model.selection_, model.n_constraints_
    assert k == {"threshold": 4}.get(rule, 2) and len(sel["limits"]) == len(sel["values"])
    fig = count.selection_figure(sel, 7)
    (ax,) = fig.axes
    (dots,) = [c for c in ax.collections if c.get_offsets().shape[0] == len(sel["values"])
               and not hasattr(c, "get_segments")]
    xy = np.asarray(dots.get_offsets())
    assert xy[:, 1] == pytest.approx(sel["values"]) and list(xy[:, 0]) == list(range(1, len(xy) + 1))
    colours = [tuple(c) for c in dots.get_facecolors()]
    assert len(set(colours[:k])) == 1 and colours[k] != colours[0]  # rows 1 … k count; row k + 1 does not
    want = [(j + 1.0, lim) for j, lim in enumerate(sel["limits"]) if lim is not None]
    assert _dashes(ax) == pytest.approx(np.array(want))
    assert sel["values"][k - 1] <= sel["limits"][k - 1] * (1 + 1e-12) and sel["values"][k] > sel["limits"][k]
    ring = next(ln for ln in ax.lines if ln.get_marker() == "o" and ln.get_markerfacecolor() == "none")
    assert (ring.get_xdata()[0], ring.get_ydata()[0]) == pytest.approx((k, sel["values"][k - 1]))
    assert sel["limit_rule"] in ax.get_title().replace("\n", " ")


def test_the_eigengap_rule_labels_each_gap_and_the_largest(arm):
    sel = StateIndependentConstraint(selection="eigengap").fit(arm.X, arm.U, groups=arm.demo).selection_
    (ax,) = count.selection_figure(sel, 7).axes
    v = np.asarray(sel["values"])
    gaps = {t.get_text(): t for t in ax.texts}
    ratios = np.maximum(v[1:], 1e-9 * v.max()) / np.maximum(v[:-1], 1e-9 * v.max())
    assert sorted(gaps) == sorted(f"×{g:.3g}" for g in ratios)
    largest = gaps[f"×{ratios.max():.3g}"]
    assert largest.get_position()[0] == pytest.approx(sel["n_constraints"] + 0.5)
    assert largest.get_color() == count.CHOSEN_COLOUR


def test_samples_not_in_time_order_show_the_ratio_rule_that_decided():
    """States and actions not sampled along trajectories (a shuffled recording): the noise rule
    cannot judge, the ratio rule on each candidate's held-out shares decides — its limit, 2 × row
    1's share, is drawn for the chosen candidate on the shares' panel, and the titles say so."""
    rng = np.random.default_rng(0)
    n = 900
    X = rng.normal(size=(n, 3))
    a = np.array([0.0, 0.0, 1.0])
    U = rng.normal(size=(n, 3))
    U -= np.outer(U @ a, a)  # one constant row: z never moves
    U += 1e-3 * rng.normal(size=U.shape)
    demo, t = np.repeat(np.arange(6), n // 6), np.tile(np.arange(n // 6) * 0.01, 6)
    model = AutoConstraint(candidates=["nhat", "per_demo"]).fit(X, U, groups=demo, t=t)
    sel = model.selection_
    winner = next(r for r in sel["candidates"] if r.get("chosen"))
    assert model.n_constraints_ == 1 and winner["noise_limit"] is None and winner["ratio_limit"][0] is None
    assert winner["share"][1] > winner["ratio_limit"][1] == pytest.approx(2 * winner["share"][0])
    fig = count.selection_figure(sel, 3)
    ratio_ax, share_ax = fig.axes
    assert _dashes(ratio_ax).size == 0  # no noise limit: the noise rule did not judge
    assert _dashes(share_ax) == pytest.approx(np.array([(2.0, winner["ratio_limit"][1])]))
    assert "ratio rule" in share_ax.get_title()
    assert "noise rule can judge (total variance" in ratio_ax.get_title().replace("\n", " ")


def test_the_noise_rule_of_a_learner_is_drawn_like_autos_on_its_training_rows():
    from ccl_cli.learn.constraint import noise_rank as nr

    ev = nr.RowEvidence(energy=np.array([1e-3, 2.0]), noise=np.array([1e-3, 1e-3]),
                        share=np.array([5e-4, 0.9]), snr=50.0)
    sel = nr.noise_rank(ev, 2).as_dict()
    ratio_ax, share_ax = count.selection_figure(sel, 3).axes
    (line,) = ratio_ax.lines
    assert line.get_ydata() == pytest.approx([1.0, 2000.0])
    assert _dashes(ratio_ax) == pytest.approx(np.array([(1.0, nr.MARGIN), (2.0, 2.0)]))
    assert _dashes(share_ax) == pytest.approx(np.array([(1.0, nr.SHARE), (2.0, nr.SHARE)]))
    assert "training" in ratio_ax.get_ylabel()
