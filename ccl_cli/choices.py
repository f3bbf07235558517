"""The run spec's fixed choices and defaults, without NumPy or pydantic: the command line lists
them in ``--help`` (and ``--version``) without importing the numerical stack or building the
spec; :mod:`ccl_cli.spec` declares its fields with them."""

from __future__ import annotations

from typing import Literal

Convention = Literal["ccl", "original"]
#: The metrics' default convention.
CONVENTION = "ccl"
#: learn-a's ``method``: which constraint estimator; ``auto`` (the default) chooses the model
#: class and the number of constraints, 0 included, by held-out evidence
ConstraintMethod = Literal["auto", "nhat", "alpha", "lambda", "linear", "per_window", "per_segment",
                           "manifold"]
DEFAULT_CONSTRAINT_METHOD = "auto"
#: learn-pi's ``projections`` (pi-coupled): from the ground truth, a learn-a stage, or either
Projections = Literal["auto", "learnt", "true"]
#: which observations a stage learns from: u, the learnt w̃ of a learn-v stage, or w̃ when there is one
On = Literal["auto", "u", "w"]
#: The share of the demonstrations (or time blocks) held out for the test set by default.
TEST_FRACTION = 0.3
