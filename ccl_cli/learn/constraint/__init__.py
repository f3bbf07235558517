"""Learners of the constraint A(x) (ALGORITHMS.md §3)."""

from ccl_cli.learn.constraint.alpha import StateDependentConstraint
from ccl_cli.learn.constraint.auto import AutoConstraint
from ccl_cli.learn.constraint.base import ConstraintModel
from ccl_cli.learn.constraint.contact_phases import ContactPhases
from ccl_cli.learn.constraint.lambda_ import KnownFeatureConstraint
from ccl_cli.learn.constraint.linear import LinearConstraint
from ccl_cli.learn.constraint.manifold import ManifoldConstraint
from ccl_cli.learn.constraint.nhat import StateIndependentConstraint
from ccl_cli.learn.constraint.none import NoConstraint
from ccl_cli.learn.constraint.per_demo import PerDemonstration
from ccl_cli.learn.constraint.segments import PerSegment
from ccl_cli.learn.constraint.stretches import ConstraintInStretches
from ccl_cli.learn.constraint.windows import PerWindow

__all__ = [
    "AutoConstraint",
    "ConstraintInStretches",
    "ConstraintModel",
    "ContactPhases",
    "KnownFeatureConstraint",
    "LinearConstraint",
    "ManifoldConstraint",
    "NoConstraint",
    "PerDemonstration",
    "PerSegment",
    "PerWindow",
    "StateDependentConstraint",
    "StateIndependentConstraint",
]
