"""Learners of the constraint A(x) (ALGORITHMS.md §3)."""

from ccl_cli.learn.constraint.alpha import StateDependentConstraint
from ccl_cli.learn.constraint.base import ConstraintModel
from ccl_cli.learn.constraint.lambda_ import KnownFeatureConstraint
from ccl_cli.learn.constraint.linear import LinearConstraint
from ccl_cli.learn.constraint.nhat import StateIndependentConstraint
from ccl_cli.learn.constraint.per_demo import PerDemonstration

__all__ = [
    "ConstraintModel",
    "KnownFeatureConstraint",
    "LinearConstraint",
    "PerDemonstration",
    "StateDependentConstraint",
    "StateIndependentConstraint",
]
