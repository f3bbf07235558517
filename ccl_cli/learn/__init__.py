"""Everything that learns: the estimators of ALGORITHMS.md §3–§5, their bases, linear
algebra, kinematics and model selection. Imports nothing above it (no I/O, no config,
no reports).

The learners are importable from here; the submodules load on first use, so
``import ccl_cli.learn.defaults`` (the command line's ``--help``) stays free of NumPy.
"""

from __future__ import annotations

from importlib import import_module
from typing import Any

_LEARNERS = {
    "StateIndependentConstraint": "ccl_cli.learn.constraint",
    "StateDependentConstraint": "ccl_cli.learn.constraint",
    "KnownFeatureConstraint": "ccl_cli.learn.constraint",
    "LinearConstraint": "ccl_cli.learn.constraint",
    "PerDemonstration": "ccl_cli.learn.constraint",
    "NullSpaceComponent": "ccl_cli.learn.nullspace",
    "PolicyLearner": "ccl_cli.learn.policy",
    "Tuned": "ccl_cli.learn.model_selection",
}

__all__ = sorted(_LEARNERS)


def __getattr__(name: str) -> Any:
    if name in _LEARNERS:
        return getattr(import_module(_LEARNERS[name]), name)
    raise AttributeError(f"module 'ccl_cli.learn' has no attribute {name!r}")
