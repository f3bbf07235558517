"""Simulated demonstrations with ground truth: the reference problems of ALGORITHMS.md §7
(:mod:`~ccl_cli.simulate.reference`) and realistic recordings
(:mod:`~ccl_cli.simulate.tracker`). Every function is seeded and returns
:class:`~ccl_cli.dataset.Demonstrations` with ``truth``."""

from __future__ import annotations

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
from ccl_cli.simulate.tracker import arm_at_rest, tracker_plane, tracker_sphere

PROBLEMS = {
    "toy2d": toy2d,
    "two_link": two_link,
    "arm7": arm7,
    "varying_constraint": varying_constraint,
    "tracker_plane": tracker_plane,
    "tracker_sphere": tracker_sphere,
    "arm_at_rest": arm_at_rest,
}

__all__ = ["LINEAR_POLICY", "PROBLEMS", "arm7", "arm_at_rest", "armesto_policy", "toy2d", "toy_policy",
           "tracker_plane", "tracker_sphere", "two_link", "two_link_constraint", "varying_constraint"]
