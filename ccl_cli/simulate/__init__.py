"""Simulated demonstrations with ground truth: the reference problems of ALGORITHMS.md §7
(:mod:`~ccl_cli.simulate.reference`), realistic recordings (:mod:`~ccl_cli.simulate.tracker`),
recordings with sensor faults, changing constraints, free phases or no constraint
(:mod:`~ccl_cli.simulate.recordings`, :mod:`~ccl_cli.simulate.wipe`), and what real logs add to
a constrained motion — compliance, tremor, drift, filtered velocities — on hinges, slides,
surfaces worked in phases and free motion (:mod:`~ccl_cli.simulate.realism`,
:mod:`~ccl_cli.simulate.mechanisms`, :mod:`~ccl_cli.simulate.contact`,
:mod:`~ccl_cli.simulate.free`). Every function is seeded and returns
:class:`~ccl_cli.dataset.Demonstrations` with ``truth``."""

from __future__ import annotations

from functools import partial

from ccl_cli.simulate.contact import contact_phases
from ccl_cli.simulate.free import handwriting, reach_goal
from ccl_cli.simulate.mechanisms import hinge, slide
from ccl_cli.simulate.recordings import flow2d, free_reach, tracker_flips, tracker_tilt
from ccl_cli.simulate.reference import (
    LINEAR_POLICY,
    arm7,
    armesto_policy,
    toy2d,
    toy_policy,
    two_link,
    two_link_constraint,
    varying_constraint,
)
from ccl_cli.simulate.settings import parse_settings
from ccl_cli.simulate.tracker import arm_at_rest, tracker_plane, tracker_sphere
from ccl_cli.simulate.wipe import arm_wipe, arm_wipe_joint, phase_subset, wipe_log

PROBLEMS = {
    "toy2d": toy2d,
    "two_link": two_link,
    "arm7": arm7,
    "varying_constraint": varying_constraint,
    "tracker_plane": tracker_plane,
    "tracker_sphere": tracker_sphere,
    "arm_at_rest": arm_at_rest,
    "tracker_flips": tracker_flips,
    "tracker_tilt": tracker_tilt,
    "arm_wipe": arm_wipe,
    "arm_wipe_force": partial(arm_wipe, force=True),  # with the force channel (base frame)
    "arm_wipe_joint": arm_wipe_joint,
    "free_reach": free_reach,
    "flow2d": flow2d,
    "hinge": hinge,
    "slide": slide,
    "contact_phases": contact_phases,
    "reach_goal": reach_goal,
    "handwriting": handwriting,
}

__all__ = [
    "LINEAR_POLICY", "PROBLEMS", "arm7", "arm_at_rest", "arm_wipe", "arm_wipe_joint", "armesto_policy",
    "contact_phases", "flow2d", "free_reach", "handwriting", "hinge", "parse_settings", "phase_subset",
    "reach_goal", "slide", "toy2d", "toy_policy", "tracker_flips", "tracker_plane", "tracker_sphere",
    "tracker_tilt", "two_link", "two_link_constraint", "varying_constraint", "wipe_log",
]
