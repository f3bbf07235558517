"""Coded warnings that say what a constant model or a policy cannot see: ``constraint_varies``
(a surface that tilts under a constant nhat) and ``not_identifiable`` (a policy direction the
constraints always hide)."""

import numpy as np
import pytest

from ccl_cli import diagnostics
from ccl_cli.app.views import constant_rows
from ccl_cli.learn.constraint import StateIndependentConstraint
from ccl_cli.simulate import recordings as sim
from ccl_cli.simulate.tracker import tracker_plane, tracker_sphere


def _varies(d):
    model = StateIndependentConstraint().fit(d.X, d.U, groups=d.demo)
    return [w["code"] for w in diagnostics.constraint_varies("learn-a", constant_rows(model, d), d, d.U)]


@pytest.mark.parametrize("seed", [1, 2, 3])
@pytest.mark.parametrize("mode", ["smooth", "steps"])
def test_a_tilting_board_under_one_constant_normal_is_flagged(mode, seed):
    assert _varies(sim.tracker_tilt(mode=mode, seed=seed)) == ["constraint_varies"]


@pytest.mark.parametrize("seed", range(4))
def test_a_bowl_under_one_constant_normal_is_flagged(seed):
    assert _varies(tracker_sphere(duration=60.0, seed=seed)) == ["constraint_varies"]


@pytest.mark.parametrize("noise", [1e-3, 2e-3])
@pytest.mark.parametrize("seed", range(4))
def test_a_flat_table_is_not(seed, noise):
    assert _varies(tracker_plane(duration=60.0, noise=noise, seed=seed)) == []


def test_policy_direction_hidden_by_a_constant_constraint():
    d = tracker_plane(duration=40.0, seed=0)
    normal = np.asarray(d.truth["A"])[0, 0] if np.ndim(d.truth["A"]) == 3 else np.asarray(d.truth["A"])[0]
    found = diagnostics.not_identifiable("learn-pi", d, d.U)
    assert [w["code"] for w in found] == ["not_identifiable"]
    assert "span 2 of 3 directions" in found[0]["message"]
    # the named direction is the table's normal
    words = found[0]["message"].split("along 1 direction(s) (")[1].split(")")[0]
    coef = {name: float(c) for c, name in (t.split("·") for t in words.split(" + "))}
    named = np.array([coef.get(n, 0.0) for n in d.action_names])
    assert abs(named @ normal) / np.linalg.norm(named) > 0.99
    free = sim.free_reach(seed=0)
    assert diagnostics.not_identifiable("learn-pi", free, free.U) == []
