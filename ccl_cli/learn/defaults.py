"""Defaults shared by the learners, the cross-validation code and the config.

A module of plain constants (no NumPy), so the command line can build its config
defaults and ``--help`` without importing the numerical stack; :mod:`ccl_cli.learn.model_selection`
re-exports them.
"""

from __future__ import annotations

#: Fewest demonstrations for cross-validating by demonstration; below it, time blocks.
MIN_DEMOS = 5
#: Fewest demonstrations for holding out whole ones as the test set (one of three leaves two to
#: learn from, whose agreement the states' geometry reads); below it, time blocks.
TEST_MIN_DEMOS = 3
#: Blocks a recording is cut into for the held-out test set.
N_BLOCKS = 10
#: Samples dropped from the training side of each train/test boundary (≥ the derivative window).
DEFAULT_GAP = 10
N_FOLDS = 5
#: Half the time span (s) of the default window of derived velocities (readers and the
#: tracker simulations): 9 samples at 50 Hz, the same 0.16 s at any rate — a window fixed
#: in samples would shrink with the rate and let sensor noise through at 500 Hz.
DERIVATIVE_HALF_SPAN_S = 0.08
#: Upper bound of that default window (samples), which keeps its memory bounded at kHz rates.
DERIVATIVE_MAX_WINDOW = 101
#: The default window (samples) when the recording has no stamps and its rate is assumed
#: (``data.time.rate``): a count of samples, so that the assumed rate only rescales the
#: velocities and nothing learnt from them depends on it (±2 samples, the default at 10 Hz).
DERIVATIVE_PACED_WINDOW = 5
#: The rule choosing the number of constraints, for every learner and the command line
#: (one source of truth: the learners' constructors and config.DEFAULTS read it; the
#: rules live in :mod:`ccl_cli.learn.constraint.rank`).
DEFAULT_RULE = "ratio"
#: ``ratio`` rule: row k is a constraint while its residual is ≤ this multiple of row 1's.
RATIO_FACTOR = 2.0
#: Window length (s) of the per-window constraint (learn/constraint/windows.py) and of the
#: per-window candidate of learn-a's ``auto`` (evidence: docs/auto.md).
WINDOW_S = 4.0
#: Hyperparameter tuning is on by default (learners' ``tune`` and the config agree).
TUNE = True
#: Model fits (candidates × folds) a learner's hyperparameter search may run (``tune:
#: {budget: n}``): a count, not seconds, so the chosen model never depends on the machine's
#: load. Every default grid fits within it (the largest, lwpi's, is 25 candidates × 3 folds).
TUNE_BUDGET = 100
#: Folds of the hyperparameter search (fewer than for choosing s: it fits many candidates).
TUNE_FOLDS = 3
#: Above this many samples the search runs on a seeded subset of about this size (whole
#: demonstrations, or spread pieces of one recording); the winner is then fitted on all.
TUNE_MAX_ROWS = 20_000
#: The policy learner of learn-pi (ALGORITHMS.md §5: the inconsistency error).
POLICY_METHOD = "pi"
