"""Honest validation, by job: :mod:`.splitters` (folds by demonstration or time blocks with
guard gaps, blocks held out inside stretches, the reported train/test split),
:mod:`.validation` (one cross-validation function), :mod:`.search` (the budgeted grid search
and :class:`Tuned`, the search as an estimator) and :mod:`.tuning` (the learners' ``tune``
parameter, :class:`Tunable`). Every name is re-exported here."""

from ccl_cli.learn.defaults import (  # noqa: F401 - the shared defaults, re-exported here
    DEFAULT_GAP,
    DEFAULT_RULE,
    MIN_DEMOS,
    N_BLOCKS,
    N_FOLDS,
    RATIO_FACTOR,
    TUNE,
    TUNE_BUDGET,
    TUNE_FOLDS,
    TUNE_MAX_ROWS,
)
from ccl_cli.learn.model_selection.search import (  # noqa: F401
    BUDGET_UNIT,
    CONSERVATIVE_GAIN,
    ROUNDING,
    STOP_EARLY,
    STOP_GAIN,
    STOP_SE,
    WIDTH,
    Budget,
    MaxRows,
    Searchable,
    SearchResult,
    Tuned,
    candidate_models,
    grid_search,
    search,
)
from ccl_cli.learn.model_selection.splitters import (  # noqa: F401
    MIN_BLOCK,
    RECORDED_GAP,
    Folds,
    Holdout,
    holdout_split,
    inner_folds,
    inner_heldout,
    make_folds,
    shape_keys,
    tuning_subset,
)
from ccl_cli.learn.model_selection.tuning import Tunable, TuneSpec, basis_grid, rbf_tunable  # noqa: F401
from ccl_cli.learn.model_selection.validation import CVResult, cross_validate, held_out_errors, take_rows  # noqa: F401
