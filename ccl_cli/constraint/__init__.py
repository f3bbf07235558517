"""Learners of the constraint A(x) (ALGORITHMS.md §3)."""

from ccl_cli.constraint.alpha import StateDependentConstraint
from ccl_cli.constraint.base import ConstraintModel, PerDemonstration
from ccl_cli.constraint.lambda_ import KnownFeatureConstraint
from ccl_cli.constraint.linear import LinearConstraint
from ccl_cli.constraint.nhat import StateIndependentConstraint

__all__ = [
    "ConstraintModel",
    "KnownFeatureConstraint",
    "LinearConstraint",
    "PerDemonstration",
    "StateDependentConstraint",
    "StateIndependentConstraint",
]
