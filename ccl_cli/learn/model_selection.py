"""Honest validation: splitters, one cross-validation function, hyperparameter tuning.

* Splitters. By demonstration when there are at least :data:`MIN_DEMOS` of them;
  otherwise contiguous time blocks (blocked K-fold), with ``gap`` samples dropped from
  the training side of every train/test boundary so that the windows of derived
  velocities (a Savitzky–Golay window of w samples makes u_n depend on x_{n±w/2}) never
  reach across it.
* :func:`cross_validate` fits a clone of any learner on each training fold and records
  its held-out error on the test fold, ``−estimator.score`` — the learner's own
  consistency error (:mod:`ccl_cli.learn.consistency`), never ground truth.
* :func:`holdout_split` chooses the reported train/test split of a recording and says why.
* :class:`Tuned` is the hyperparameter search as an estimator: a grid searched by
  cross-validation within a budget counted in model fits (candidates × folds), never in
  seconds, so the same data and settings give the same model on any machine at any
  load. The learners' ``tune`` parameter delegates to it (:class:`Tunable`). The search
  costs a few fits (:func:`search`): a candidate's folds share work (a closed-form
  learner's normal equations are summed once and downdated per fold; an iterative
  learner's folds start from its fit of all rows, seen through each fold's rows),
  candidates on one basis share it, the grid runs from the smallest basis up and stops
  where a larger one does not help, and large data are searched on a seeded subset.
"""

from __future__ import annotations

import itertools
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Annotated, Any, ClassVar

import numpy as np

from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.learn import blas
from ccl_cli.learn.base import Estimator, check_xu, clone
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
from ccl_cli.learn.params import Fields, Interval, NFolds, Seed, parameters
from ccl_cli.progress import progress_of


# -- splitters ------------------------------------------------------------------------------
@dataclass
class Folds:
    """Train/test index pairs and how they were made."""

    pairs: list[tuple[np.ndarray, np.ndarray]]
    kind: str  # "demonstrations" | "blocks"
    reason: str


def _blocks(n: int, n_blocks: int) -> list[np.ndarray]:
    return [b for b in np.array_split(np.arange(n), n_blocks) if b.size]


def _guarded_train(n: int, test: np.ndarray, gap: int) -> np.ndarray:
    """Indices not in ``test`` and more than ``gap`` samples from any test index."""
    is_test = np.zeros(n, bool)
    is_test[test] = True
    near = is_test.copy()
    if gap > 0:
        # distance to the nearest test sample via a dilation by ``gap`` on each side
        csum = np.concatenate([[0], np.cumsum(is_test)])
        lo = np.clip(np.arange(n) - gap, 0, n)
        hi = np.clip(np.arange(n) + gap + 1, 0, n)
        near = (csum[hi] - csum[lo]) > 0
    return np.flatnonzero(~near)


def make_folds(groups: np.ndarray | None, n: int, n_folds: int = N_FOLDS, seed: int = 0,
               gap: int = DEFAULT_GAP, min_demos: int = MIN_DEMOS) -> Folds:
    """K folds over demonstrations (``groups``: demo id per sample) when there are at
    least ``min_demos`` of them, else K contiguous blocks of samples with guard gaps."""
    groups = np.zeros(n, int) if groups is None else np.asarray(groups)
    ids = np.unique(groups)
    if len(ids) >= max(min_demos, 2):
        k = min(n_folds, len(ids))
        perm = np.random.default_rng(seed).permutation(ids)
        pairs = []
        for part in np.array_split(perm, k):
            test = np.isin(groups, part)
            pairs.append((np.flatnonzero(~test), np.flatnonzero(test)))
        return Folds(pairs, "demonstrations", f"{len(ids)} demonstrations ≥ {min_demos}: "
                     f"{k} folds by demonstration")
    if n < n_folds * (2 * gap + 4):
        raise InputError(f"cross-validation over time blocks needs at least {n_folds * (2 * gap + 4)} "
                         f"samples ({n_folds} blocks, guard gaps of {gap}), got {n}")
    pairs = [(_guarded_train(n, b, gap), b) for b in _blocks(n, n_folds)]
    return Folds(pairs, "blocks", f"{len(ids)} demonstration(s) < {min_demos}: {n_folds} contiguous "
                 f"time blocks, {gap} samples dropped from training at each boundary")


#: Guard gap (samples) around held-out blocks of recorded actions (neighbours share no filter;
#: two keep a second difference's samples apart); derived ones use the derivative window.
RECORDED_GAP = 2
#: Smallest held-out block inside a segment (samples).
MIN_BLOCK = 4


def inner_folds(segments: np.ndarray, n_folds: int = N_FOLDS, gap: int = DEFAULT_GAP,
                what: str = "segment") -> Folds:
    """K folds of held-out blocks *inside* every segment (a time window of a demonstration, or
    a whole demonstration): each segment's samples, in order, are cut into K contiguous
    blocks, and fold j holds out block (j + segment number) mod K of every segment — so each
    fold's held-out samples are spread over the recording — with the training samples within
    ``gap`` of a held-out one dropped. For models fitted per segment, which can only be
    tested on their own segments. ``segments`` (N,): segment number per sample, 0 … S−1."""
    seg = np.asarray(segments).astype(np.int64)
    n = len(seg)
    order = np.argsort(seg, kind="stable")
    counts = np.bincount(seg)
    first = np.cumsum(counts) - counts
    pos = np.empty(n, np.int64)
    pos[order] = np.arange(n) - np.repeat(first, counts)
    block = (pos * n_folds) // counts[seg]
    fold = (block + seg) % n_folds
    pairs = [(_guarded_train(n, np.flatnonzero(fold == j), gap), np.flatnonzero(fold == j))
             for j in range(n_folds)]
    return Folds(pairs, "inner blocks", f"{n_folds} folds of contiguous blocks held out inside every "
                 f"{what} ({len(counts)}), {gap} samples dropped from training at each boundary")


def inner_heldout(segments: np.ndarray, derivative: dict | bool | None,
                  error_of: Callable[[np.ndarray, np.ndarray], float], what: str = "segment"
                  ) -> dict[str, Any] | None:
    """The held-out NPOE of a model fitted per segment (a demonstration or a window), which can
    be tested only on its own segments: :data:`N_FOLDS` :func:`inner_folds` of ``segments`` (N,)
    with the guard gap of how U was made (``derivative``: its window when derived, else
    :data:`RECORDED_GAP`); ``error_of(train, test)`` fits on the rows ``train`` and returns the
    error on the rows ``test``. {error, mean, se, per_fold, folds}, or None when most segments
    are too short for the blocks and their gaps."""
    gap = int(derivative["window"]) if isinstance(derivative, dict) else RECORDED_GAP
    seg = np.asarray(segments)
    counts = np.bincount(seg)
    if (counts[seg] >= N_FOLDS * (2 * gap + MIN_BLOCK)).mean() < 0.5:
        return None
    folds = inner_folds(seg, N_FOLDS, gap, what)
    e = np.array([error_of(train, test) for train, test in folds.pairs])  # a loop over the folds
    return {"error": "NPOE", "mean": float(e.mean()), "se": float(e.std(ddof=1) / np.sqrt(len(e))),
            "per_fold": e.tolist(), "folds": folds.reason}


# -- cross-validation -----------------------------------------------------------------------
@dataclass
class CVResult:
    """Held-out errors (lower is better) per fold, and how the folds were made."""

    errors: np.ndarray  # (n_folds,) or (n_folds, m)
    kind: str
    reason: str

    @property
    def mean(self) -> np.ndarray | float:
        return self.errors.mean(0)

    @property
    def se(self) -> np.ndarray | float:
        k = self.errors.shape[0]
        return self.errors.std(0, ddof=1) / np.sqrt(k) if k > 1 else np.zeros_like(self.mean)


def cross_validate(
    estimator: Any,
    X: np.ndarray,
    U: np.ndarray,
    groups: np.ndarray | None = None,
    *,
    folds: Folds | None = None,
    n_folds: int = N_FOLDS,
    seed: int = 0,
    gap: int = DEFAULT_GAP,
    scorer: Callable[..., float | np.ndarray] | None = None,
    projections: np.ndarray | None = None,
) -> CVResult:
    """Fit a clone of ``estimator`` on each training fold, measure its error on the test fold.

    Args:
        estimator: any learner of this package (unfitted; it is cloned per fold).
        X (N, p), U (N, q): states and actions; groups (N,): demonstration ids.
        folds: explicit folds; by default :func:`make_folds` (by demonstration when
            there are enough, else contiguous blocks with ``gap``-sample guards).
        scorer: ``scorer(model, X_test, U_test, groups_test)`` → an error (float or (m,)
            array); default ``−model.score(X_test, U_test, groups=groups_test)``.
        projections: (N, q, q) Ñ per sample for ``pi-coupled`` (subset per fold).

    Returns:
        :class:`CVResult` with ``errors`` (n_folds,) or (n_folds, m).
    """
    X = np.asarray(X, dtype=float)
    U = np.asarray(U, dtype=float)
    n = len(U)
    groups = np.zeros(n, int) if groups is None else np.asarray(groups)
    folds = folds or make_folds(groups, n, n_folds, seed, gap)
    out = []
    for train, test in folds.pairs:
        model = clone(estimator)
        extra = {} if projections is None else {"projections": projections[train]}
        model.fit(X[train], U[train], groups=groups[train], **extra)
        if scorer is not None:
            out.append(scorer(model, X[test], U[test], groups[test]))
        else:
            extra = {} if projections is None else {"projections": projections[test]}
            out.append(-model.score(X[test], U[test], groups=groups[test], **extra))
    return CVResult(np.asarray(out, dtype=float), folds.kind, folds.reason)


# -- the reported train/test split ----------------------------------------------------------
@dataclass
class Holdout:
    train: np.ndarray  # bool (N,)
    test: np.ndarray  # bool (N,)
    info: dict[str, Any] = field(default_factory=dict)


def holdout_split(demo: np.ndarray, fraction: float = 0.3, seed: int = 0, gap: int = DEFAULT_GAP,
                  min_demos: int = MIN_DEMOS, n_blocks: int = N_BLOCKS) -> Holdout:
    """The reported train/test split: by demonstration when there are at least
    ``min_demos``; else ``n_blocks`` contiguous time blocks of which round(fraction ·
    n_blocks) (seeded) are held out, with ``gap`` samples dropped from training at each
    boundary. ``info``: kind, reason, n_train/n_test demos or blocks, samples, gap."""
    if not 0.0 < fraction < 1.0:
        raise InputError(f"test fraction must be in (0, 1), got {fraction}")
    demo = np.asarray(demo)
    n = len(demo)
    ids = np.unique(demo)
    rng = np.random.default_rng(seed)
    possible = min(n_blocks, n // (2 * gap + 4))  # blocks long enough for their guard gaps
    if len(ids) >= max(min_demos, 2) or (possible < 3 and len(ids) >= 2):
        n_test = min(max(1, int(round(fraction * len(ids)))), len(ids) - 1)
        test_ids = rng.choice(ids, size=n_test, replace=False)
        test = np.isin(demo, test_ids)
        why = (f"{len(ids)} demonstrations (≥ {min_demos})" if len(ids) >= min_demos else
               f"only {len(ids)} demonstrations (< {min_demos}) but {n} samples are too few for "
               f"time blocks with guard gaps of {gap}")
        info = {"kind": "demonstrations", "reason": f"{why}: {n_test} held out whole",
                "n_train_demos": int(len(ids) - n_test), "n_test_demos": int(n_test)}
        return Holdout(~test, test, {**info, "n_train_samples": int((~test).sum()),
                                     "n_test_samples": int(test.sum()), "fraction": fraction})
    if possible < 3:
        raise InputError(f"{n} samples in one demonstration are too few for a held-out test set of "
                         f"time blocks (need ≥ {3 * (2 * gap + 4)}); add demonstrations or set "
                         "data.test.fraction: 0")
    blocks = _blocks(n, possible)
    n_test = min(max(1, int(round(fraction * len(blocks)))), len(blocks) - 1)
    chosen = np.sort(rng.choice(len(blocks), size=n_test, replace=False))
    test_idx = np.concatenate([blocks[i] for i in chosen])
    train_idx = _guarded_train(n, test_idx, gap)
    train = np.zeros(n, bool)
    train[train_idx] = True
    test = np.zeros(n, bool)
    test[test_idx] = True
    why = ("a single continuous recording" if len(ids) == 1 else f"only {len(ids)} demonstrations")
    info = {"kind": "blocks",
            "reason": f"{why} (< {min_demos}): {n_test} of {len(blocks)} contiguous time blocks held out, "
                      f"{gap} samples dropped from training at each boundary",
            "n_train_blocks": int(len(blocks) - n_test), "n_test_blocks": int(n_test),
            "test_blocks": [int(i) for i in chosen], "gap": int(gap),
            "n_train_samples": int(train.sum()), "n_test_samples": int(test.sum()),
            "n_dropped_samples": int(n - train.sum() - test.sum()), "fraction": fraction}
    return Holdout(train, test, info)


# -- hyperparameter tuning ------------------------------------------------------------------
def tuning_subset(groups: np.ndarray | None, n: int, seed: int = 0,
                  max_rows: int | None = None) -> tuple[np.ndarray, np.ndarray, str] | None:
    """Rows on which to search hyperparameters when there are more than ``max_rows``
    (default :data:`TUNE_MAX_ROWS`): whole demonstrations in a seeded random order until
    about ``max_rows`` samples (at least :data:`MIN_DEMOS` of them), or — with fewer
    demonstrations than that — :data:`N_BLOCKS` contiguous pieces spread over each
    recording, which then act as the groups of the search's folds.

    Returns (row indices (m,), their groups (m,), a sentence saying what was taken), or
    None when all rows are used.
    """
    max_rows = int(max_rows or TUNE_MAX_ROWS)
    if n <= max_rows:
        return None
    g = np.zeros(n, int) if groups is None else np.asarray(groups)
    ids, sizes = np.unique(g, return_counts=True)
    rng = np.random.default_rng(seed)
    if len(ids) >= MIN_DEMOS:
        order = rng.permutation(len(ids))
        take = np.cumsum(sizes[order]) <= max_rows
        take[:MIN_DEMOS] = True
        chosen = ids[order[take]]
        rows = np.flatnonzero(np.isin(g, chosen))
        if len(rows) < n:
            return rows, g[rows], (f"searched on {len(rows)} of {n} samples: {len(chosen)} of "
                                   f"{len(ids)} whole demonstrations (seed {seed})")
        return None
    piece = max_rows // N_BLOCKS
    starts = np.linspace(0, n - piece, N_BLOCKS).astype(int)
    rows = (starts[:, None] + np.arange(piece)[None, :]).ravel()
    return rows, np.repeat(np.arange(N_BLOCKS), piece), (
        f"searched on {len(rows)} of {n} samples: {N_BLOCKS} contiguous pieces of {piece} "
        "spread over the recording, each a group of the folds")


#: A search's budget: model fits (candidates × folds); its rows at most.
Budget = Annotated[float, Interval(0, None)]
MaxRows = Annotated[int, Interval(100, None)]
#: ``tune`` of a learner: True (the default search), False, or a mapping adjusting it.
TuneSpec = bool | Annotated[dict, Fields(budget=Budget, folds=NFolds, max_rows=MaxRows, grid=dict)]
#: What ``budget`` and ``budget_used`` count.
BUDGET_UNIT = "fits (candidates × folds)"


def take_rows(fit_kw: dict[str, Any], rows: np.ndarray) -> dict[str, Any]:
    """The per-sample arguments of ``fit`` (e.g. ``projections`` (N, q, q)) for ``rows``."""
    return {k: None if v is None else np.asarray(v)[rows] for k, v in fit_kw.items()}


def candidate_models(estimator: Any, X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds,
                     basis: Any = None, shared: dict[Any, Any] | None = None, **fit_kw: Any
                     ) -> tuple[Any | None, list[Any]]:
    """The models one candidate's cross-validation needs: (the candidate fitted on all of X
    (N, p), U (N, q), or None; one model per training fold of ``folds``).

    A :class:`Tunable` learner shares work between them (:meth:`Tunable._cv_models`: one
    basis, normal equations downdated per fold, folds started from the all-rows fit);
    any other estimator is cloned and fitted per fold. ``basis``: a fitted feature map
    to use (Tunable learners only; None: fitted on X); ``shared``: a store the search keeps for
    its candidates on the same data and folds (e.g. normal equations of a basis)."""
    if isinstance(estimator, Tunable):
        return estimator._cv_models(X, U, groups, folds, basis=basis, shared=shared, **fit_kw)
    models = [clone(estimator).fit(X[train], U[train], groups=groups[train], **take_rows(fit_kw, train))
              for train, _ in folds.pairs]
    return None, models


def held_out_errors(models: list[Any], X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds,
                    **fit_kw: Any) -> np.ndarray:
    """−model.score on each test fold (the learner's own consistency error): (n_folds,)."""
    return np.array([-m.score(X[test], U[test], groups=groups[test], **take_rows(fit_kw, test))
                     for m, (_, test) in zip(models, folds.pairs, strict=True)], dtype=float)


@dataclass
class SearchResult:
    """What :func:`search` found: the chosen parameters, the report's summary, scikit-learn's
    ``cv_results_``, and the winner's model fitted on all searched rows (None when the
    search does not keep one) with its fitted basis (None: none shared)."""

    chosen: dict[str, Any]
    info: dict[str, Any]
    cv_results: dict[str, Any]
    full: Any = None
    basis: Any = None


#: Stop the search at the first basis size that does not lower the held-out error (:func:`search`).
STOP_EARLY = True
#: ... by more than this many standard errors of the paired difference over the folds ...
STOP_SE = 0.5
#: ... and by more than this fraction of the best mean error.
STOP_GAIN = 0.01
#: A ``TUNE_CONSERVATIVE`` parameter leaves its configured value only for a held-out error lower
#: by more than this fraction (and STOP_SE): a smaller cut-off gains orders of magnitude on
#: noise-free data and a few per cent of noise on noisy data (docs/measurements.md, "pi and lwpi").
CONSERVATIVE_GAIN = 0.1


#: Normalised held-out errors below this are rounding (the fit reproduces the held-out data; a
#: relative residual of 1e-10): a larger basis never beats another by less.
ROUNDING = 1e-20


def _improves(errors: np.ndarray, best: np.ndarray, larger: bool, gain: float = STOP_GAIN) -> bool:
    """Whether fold errors ``errors`` beat ``best`` (n_folds,): a lower mean; for a larger basis
    than the best's, lower by more than STOP_SE standard errors of the paired difference, by
    more than ``gain`` of the best mean and by more than :data:`ROUNDING`."""
    diff = errors - best
    if not larger:
        return bool(diff.mean() < 0)
    se = diff.std(ddof=1) / np.sqrt(len(diff)) if len(diff) > 1 else 0.0
    return bool(diff.mean() < -max(STOP_SE * se, gain * float(best.mean()), ROUNDING))


#: In ``TUNE_CONSERVATIVE``: the width factor of an RBF basis candidate (its ``sigma2``), whose
#: first value is the default rule's width (ALGORITHMS.md §2).
WIDTH = "width"


def _held_back(best: int, rows: list[dict[str, Any]], errors: list[np.ndarray], grid: dict[str, list[Any]],
               conservative: tuple[str, ...]) -> int:
    """The winner, moved back along each ``conservative`` parameter (its values in the grid's
    order, the first the most regularising; :data:`WIDTH`: the basis with the default width):
    to the earliest value whose candidate (the same otherwise) the winner does not beat by
    :data:`STOP_SE` and :data:`CONSERVATIVE_GAIN` (:func:`_improves`)."""
    for key in conservative:
        if key == WIDTH:  # an RBF width factor: the default rule's width (no sigma2) is the first value
            basis = rows[best]["params"].get("basis")
            if isinstance(basis, dict) and "sigma2" in basis:
                plain = {**rows[best]["params"], "basis": {k: v for k, v in basis.items() if k != "sigma2"}}
                rival = next((i for i, r in enumerate(rows) if r["params"] == plain), None)
                if rival is not None and not _improves(errors[best], errors[rival], True, CONSERVATIVE_GAIN):
                    best = rival
            continue
        if key not in grid:
            continue
        order = grid[key]
        params = rows[best]["params"]
        rivals = [i for i, r in enumerate(rows) if r["params"][key] != params[key]
                  and all(r["params"][k] == params[k] for k in params if k != key)
                  and order.index(r["params"][key]) < order.index(params[key])]
        for i in sorted(rivals, key=lambda i: order.index(rows[i]["params"][key])):
            if not _improves(errors[best], errors[i], True, CONSERVATIVE_GAIN):
                best = i
                break
    return best


def _size(params: dict[str, Any]) -> float:
    """How large a candidate's basis is (its number of centres; 0 when it names none): the
    order in which :func:`search` runs the candidates and stops."""
    basis = params.get("basis")
    k = basis.get("n_centres") if isinstance(basis, dict) else params.get("n_centres")
    return float(k) if isinstance(k, int | float) and not isinstance(k, bool) else 0.0


def search(
    estimator: Any,
    X: np.ndarray,
    U: np.ndarray,
    groups: np.ndarray | None,
    grid: dict[str, list[Any]],
    *,
    budget: float = TUNE_BUDGET,
    n_folds: int = N_FOLDS,
    seed: int = 0,
    gap: int = DEFAULT_GAP,
    basis_data: tuple[np.ndarray, np.ndarray] | None = None,
    **fit_kw: Any,
) -> SearchResult:
    """Grid search by cross-validation within ``budget`` model fits (candidates × folds).

    Candidates run from the smallest basis up (their number of centres; the grid's order
    among equals, so the configured basis comes first of its size), and the search stops at
    the first size that does not beat the best so far: a larger basis counts as better only
    when its fold errors are lower by more than :data:`STOP_SE` standard error of the paired
    difference and by more than :data:`STOP_GAIN` of the best's mean (held-out errors that
    only fluctuate, or gain a fraction of a per cent, do not call for a costlier model); still
    larger bases cost more and, measured on the tutorials and at N = 1e4–1e5, were not better
    after such a step (docs/measurements.md, "Tuning"). Of the candidates run, the smallest
    mean held-out error wins (the first of equals) — except that along a parameter the
    estimator lists in ``TUNE_CONSERVATIVE`` (e.g. the cut-off of a pseudo-inverse, its
    configured value first) the winner keeps the earliest value it does not beat by STOP_SE
    and :data:`CONSERVATIVE_GAIN`. Each candidate costs ``n_folds`` fits and runs while
    the fits so far plus its own stay within ``budget`` (the first always runs); the rest,
    and those after the stop, are counted in ``skipped``. Nothing depends on the machine or
    its load. A candidate's fits share work (:func:`candidate_models`), and candidates that
    differ only in other settings than the basis share its fit (and, for a closed-form
    learner, its normal equations); the basis is fitted on ``basis_data`` (X, U) when given
    (all the rows, when the search runs on a subset of them), else on X.

    Returns:
        :class:`SearchResult`; ``info`` = {"grid", "scores": [{params, mean, se}] in the
        order run, "chosen", "budget", "budget_used", "budget_unit", "skipped", "stopped"
        (why larger candidates did not run, or None), "folds", "rule"}.
    """
    if not grid:
        raise ConfigError("tuning needs a non-empty grid")
    keys = list(grid)
    combos = [dict(zip(keys, vals, strict=True)) for vals in itertools.product(*(grid[k] for k in keys))]
    combos.sort(key=_size)  # stable: the grid's order among candidates of one size
    n = len(U)
    groups = np.zeros(n, int) if groups is None else np.asarray(groups)
    folds = make_folds(groups, n, n_folds, seed, gap)
    per_candidate = len(folds.pairs)  # fits
    rows: list[dict[str, Any]] = []
    ran: list[tuple[dict[str, Any], np.ndarray]] = []
    first_failure = ""  # why the first candidate that could not be fitted failed (for the error)
    kept: list[tuple[Any, Any]] = []  # (full model, basis) of each row of ``rows``
    ran_errors: list[np.ndarray] = []  # fold errors of each row of ``rows``
    bases: dict[tuple, Any] = {}  # fitted bases by their settings (candidates differing in others share one)
    shared: dict[Any, Any] = {}  # what candidates on one basis share (a closed-form learner's equations)
    used = skipped = 0
    stopped: str | None = None
    best: int | None = None  # the row of the candidate the stopping rule holds best so far
    incumbent: int | None = None  # the same, when the previous size began
    with progress_of("tuning, candidates", len(combos)) as advance:
        for i, params in enumerate(combos):
            advance(1 if i else 0)  # candidates begun so far, for the progress display
            if i and _size(params) != _size(combos[i - 1]):  # a size is complete
                if STOP_EARLY and incumbent is not None and best == incumbent:
                    stopped = (f"{_size(combos[i - 1]):g} centres did not lower the held-out error of "
                               f"fewer centres by more than {STOP_SE:g} standard error of the paired "
                               f"difference and {STOP_GAIN:.0%}: larger bases not run")
                    skipped += len(combos) - i
                    break
                incumbent = best
            if used and used + per_candidate > budget:
                skipped += 1
                continue
            used += per_candidate
            candidate = clone(estimator).set_params(**params)
            try:
                basis = None
                if isinstance(candidate, Tunable):  # one fitted basis per distinct basis setting
                    key = candidate._basis_key()
                    if key not in bases:
                        bases[key] = candidate._fit_basis(*(basis_data or (X, U)))
                    basis = bases[key]
                full, models = candidate_models(candidate, X, U, groups, folds, basis, shared, **fit_kw)
                if isinstance(candidate, Tunable):
                    errors = candidate._held_out_errors(models, X, U, groups, folds, shared=shared, **fit_kw)
                else:
                    errors = held_out_errors(models, X, U, groups, folds, **fit_kw)
            except (InputError, LearningError, np.linalg.LinAlgError) as exc:
                ran.append((params, np.full(per_candidate, np.nan)))
                first_failure = first_failure or f"{params}: {exc}"
                continue  # e.g. more centres than training samples in a fold
            ran.append((params, errors))
            mean = float(errors.mean())
            se = float(errors.std(ddof=1) / np.sqrt(len(errors))) if len(errors) > 1 else 0.0
            rows.append({"params": params, "mean": mean if np.isfinite(mean) else float("inf"), "se": se})
            kept.append((full, basis if basis is not None else getattr(full, "basis_", None)))
            if np.isfinite(mean) and (best is None or _improves(
                    errors, ran_errors[best], _size(params) > _size(rows[best]["params"]))):
                best = len(rows) - 1
            ran_errors.append(errors)
    if best is None:
        raise InputError("no hyperparameter candidate could be cross-validated on this data (the first "
                         f"failed with {first_failure})"[:600])
    best = min(range(len(rows)), key=lambda i: rows[i]["mean"])  # of those run, the first of equals
    best = _held_back(best, rows, ran_errors, grid, getattr(estimator, "TUNE_CONSERVATIVE", ()))
    chosen = rows[best]["params"]
    info = {"grid": {k: list(v) for k, v in grid.items()}, "scores": rows, "chosen": chosen,
            "budget": budget, "budget_used": used, "budget_unit": BUDGET_UNIT, "skipped": skipped,
            "stopped": stopped, "folds": {"kind": folds.kind, "n": per_candidate, "reason": folds.reason},
            "rule": (f"smallest mean held-out error; larger bases run while each lowers it by more "
                     f"than {STOP_SE:g} standard error of the paired difference and {STOP_GAIN:.0%}")}
    return SearchResult(chosen, info, _cv_results(ran, keys), *kept[best])


def grid_search(estimator: Any, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None,
                grid: dict[str, list[Any]], *, projections: np.ndarray | None = None, **options: Any
                ) -> tuple[dict[str, Any], dict[str, Any], dict[str, Any]]:
    """:func:`search` (``options``: its budget, n_folds, seed, gap) as (chosen parameters, info,
    cv_results) — cv_results in the layout of scikit-learn's ``GridSearchCV.cv_results_``
    (scores = −errors; candidates that failed have NaN)."""
    extra = {} if projections is None else {"projections": projections}
    found = search(estimator, X, U, groups, grid, **options, **extra)
    return found.chosen, found.info, found.cv_results


def _cv_results(ran: list[tuple[dict[str, Any], np.ndarray]], keys: list[str]) -> dict[str, Any]:
    """scikit-learn's ``cv_results_`` layout: one entry per candidate that ran."""
    scores = -np.array([errors for _, errors in ran])  # (candidates, folds)
    mean = scores.mean(1)
    ordered = np.where(np.isnan(mean), -np.inf, mean)
    rank = 1 + np.sum(ordered[None, :] > ordered[:, None], axis=1)  # equal scores share a rank
    out: dict[str, Any] = {"params": [p for p, _ in ran],
                           **{f"param_{k}": [p.get(k) for p, _ in ran] for k in keys},
                           "mean_test_score": mean, "std_test_score": scores.std(1), "rank_test_score": rank}
    out.update({f"split{i}_test_score": scores[:, i] for i in range(scores.shape[1])})
    return out


class Tuned(Estimator):
    """``estimator`` with its hyperparameters chosen from ``grid`` by cross-validation.

    Args:
        estimator: an unfitted learner (cloned, never changed).
        grid: parameter → candidates, searched in order (the first: the default).
        folds: folds of the search (None: the estimator's ``TUNE_FOLDS``, else
            :data:`TUNE_FOLDS`); by demonstration when there are enough, else time blocks.
        budget: the most model fits the search may run, candidates × folds (None: the
            estimator's ``TUNE_BUDGET``, else :data:`TUNE_BUDGET`); the first candidate always runs.
        max_rows: above this many samples the search runs on a seeded subset
            (:func:`tuning_subset`; None: the estimator's ``TUNE_MAX_ROWS``, else
            :data:`TUNE_MAX_ROWS`); the winner is fitted on all (a :class:`Tunable` learner
            starts that fit from its search fit).
        seed: of the folds and the subset.

    Attributes:
        best_estimator_ (the winner fitted on all of X, U), best_params_, best_score_
        (−its mean held-out error), cv_results_ (scikit-learn's layout), tuning_ (what
        the report shows: grid, scores, chosen, budget, budget_used, budget_unit, skipped,
        folds, rule, subset; or {chosen: None, reason} when the data are too few to
        cross-validate, and the estimator is then fitted as given), n_features_in_.
        Other learnt attributes (``n_constraints_``, ``W_``, ...) are read from the winner.
    """

    def __init__(self, estimator: Estimator, grid: dict[str, list[Any]], *, folds: NFolds | None = None,
                 budget: Budget | None = None, max_rows: MaxRows | None = None, seed: Seed = 0) -> None:
        self._store_params(locals())

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None, **fit_kw: Any) -> Tuned:
        """Search on X (N, p), U (N, q) with demonstration ids ``groups`` (N,); ``fit_kw``
        (e.g. ``projections`` (N, q, q) of pi-coupled) go to every fit, subset per fold."""
        self._validate_params()
        X, U = check_xu(X, U)
        n = len(U)
        est = self.estimator
        folds = int(self.folds or getattr(est, "TUNE_FOLDS", None) or TUNE_FOLDS)
        groups = np.zeros(n, int) if groups is None else np.asarray(groups)
        Xs, Us, gs, kw = X, U, groups, fit_kw
        subset = tuning_subset(groups, n, self.seed, self.max_rows or getattr(est, "TUNE_MAX_ROWS", None))
        if subset is not None:  # large N: search on a seeded subset, fit the winner on all
            rows, gs, subset_note = subset
            Xs, Us, kw = X[rows], U[rows], take_rows(fit_kw, rows)
        found: SearchResult | None = None
        with blas.threads(1):  # one BLAS thread, as every learner's fit (Tunable._fit)
            try:
                make_folds(gs, len(Us), folds, 0, DEFAULT_GAP)
            except InputError as exc:  # too little data to cross-validate: say so, fit as given
                self.tuning_: dict[str, Any] = {"chosen": None, "reason": f"not tuned: {exc.message}"}
                self.cv_results_: dict[str, Any] = {}
            else:
                budget = self.budget if self.budget is not None else getattr(est, "TUNE_BUDGET", None)
                found = search(est, Xs, Us, gs, self.grid, budget=TUNE_BUDGET if budget is None else budget,
                               n_folds=folds,
                               seed=self.seed, basis_data=None if subset is None else (X, U), **kw)
                self.tuning_, self.cv_results_ = found.info, found.cv_results
                if subset is not None:
                    self.tuning_["subset"] = subset_note
                if getattr(est, "tune_scored_on", None):  # a learner that scores a part of the rows
                    self.tuning_["scored_on"] = est.tune_scored_on
            chosen = found.chosen if found is not None else {}
            winner = clone(est).set_params(**chosen)
            if found is not None and found.full is not None and subset is None:
                self.best_estimator_ = found.full  # the search fitted the winner on all rows already
            elif found is not None and isinstance(winner, Tunable):
                self.best_estimator_ = winner._fit_given(X, U, groups=groups, basis=found.basis,
                                                         start=found.full, **fit_kw)
            else:
                self.best_estimator_ = winner.fit(X, U, groups=groups, **fit_kw)
        self.best_params_ = chosen
        self.best_score_ = -min((r["mean"] for r in self.tuning_.get("scores", [])), default=np.nan)
        if hasattr(self.best_estimator_, "n_features_in_"):
            self.n_features_in_ = self.best_estimator_.n_features_in_
        return self

    def __getattr__(self, name: str) -> Any:
        """Learnt attributes (``..._``) of the winner, e.g. ``n_constraints_``."""
        if name.endswith("_") and not name.startswith("_") and "best_estimator_" in vars(self):
            return getattr(vars(self)["best_estimator_"], name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def _best(self) -> Any:
        self._check_fitted("best_estimator_")
        return self.best_estimator_

    def predict(self, X: np.ndarray) -> np.ndarray:
        """The winner's prediction (w̃ or π̃): (N, p) → (N, q)."""
        return self._best().predict(X)

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        """The winner's Ñ(X): (N, p) → (N, q, q)."""
        return self._best().projection(X, groups=groups)

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None) -> np.ndarray:
        """The winner's Ã(X): (N, p) → (N, s, q)."""
        return self._best().constraint(X, groups=groups)

    def score(self, X: np.ndarray, U: np.ndarray, **kw: Any) -> float:
        """The winner's score (minus its own consistency error; higher is better)."""
        return self._best().score(X, U, **kw)


@parameters
class Tunable:
    """The ``tune`` parameter of a learner (True by default): when on, ``fit`` delegates
    to :class:`Tuned` over the learner's default grid (:meth:`_tune_grid`) or the grid
    given in ``tune: {grid: ...}`` and takes over the winner's learnt attributes;
    ``tuning_`` records the search. The constructor parameters are left unchanged.

    A learner lists its basis candidates in :meth:`_basis_candidates`; only a default
    RBF basis is tuned (:func:`rbf_tunable`). Its fit is split so that a search can share
    work: :meth:`_fit_basis` (the feature map), :meth:`_fit_core` (the fit given a fitted
    basis and, optionally, a fitted model to start from) and :meth:`_cv_models` (the models
    of one candidate's cross-validation)."""

    #: Folds of this learner's default search (None: :data:`TUNE_FOLDS`).
    TUNE_FOLDS: ClassVar[int | None] = None
    #: Rows of this learner's search above which it runs on a subset (None: :data:`TUNE_MAX_ROWS`).
    TUNE_MAX_ROWS: ClassVar[int | None] = None
    #: Fits its default search may run (None: :data:`TUNE_BUDGET`).
    TUNE_BUDGET: ClassVar[float | None] = None
    #: Grid parameters whose first value a search leaves only on clear held-out evidence
    #: (regularisation; :func:`search`).
    TUNE_CONSERVATIVE: ClassVar[tuple[str, ...]] = ()
    #: The parameters its feature map depends on (:meth:`_fit_basis`, :meth:`_basis_key`).
    BASIS_PARAMS: ClassVar[tuple[str, ...]] = ("basis", "n_centres", "seed")
    tune: TuneSpec = TUNE

    def _basis_candidates(self) -> list[tuple[tuple[int, ...], tuple[float, ...]]]:
        """(numbers of centres, width factors) of the candidate bases, in order (:func:`basis_grid`)."""
        return []

    def _tune_grid(self, X: np.ndarray, U: np.ndarray) -> dict[str, list[Any]]:
        """The grid searched when ``tune`` is on: ``{"basis": [candidates]}`` with the
        configured basis first, or {} (nothing to tune: a basis the user fixed, or too few
        samples for any candidate)."""
        if not rbf_tunable(self.basis):
            return {}
        grid = [spec for sizes, widths in self._basis_candidates()
                for spec in basis_grid(X, sizes, widths, self.seed)]
        return {"basis": grid} if grid else {}

    # -- the fit in parts ------------------------------------------------------------------
    def _fit_basis(self, X: np.ndarray, U: np.ndarray) -> Any:
        """The learner's feature map (its ``basis``, ``n_centres`` and ``seed``) fitted on the
        states X (N, p) of a fit with actions U (N, q)."""
        from ccl_cli.learn.basis import make_basis

        return make_basis(self.basis, self.n_centres, self.seed).fit(X)

    def _basis_key(self) -> tuple:
        """What :meth:`_fit_basis` depends on (the values of :attr:`BASIS_PARAMS`), hashable:
        candidates with equal keys share one fitted basis in a search."""
        return tuple(_frozen(getattr(self, name)) for name in self.BASIS_PARAMS)

    def _fit_core(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                  basis: Any = None, start: Any = None, **fit_kw: Any) -> Any:
        """The untuned fit on checked X (N, p), U (N, q): with ``basis`` (fitted; None: the
        learner's own, :meth:`_fit_basis`) and ``start``, a fitted model of the same learner
        and basis to start an iterative fit from (None: the learner's own start)."""
        raise NotImplementedError

    def _fit_given(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None, basis: Any = None,
                   start: Any = None, **fit_kw: Any) -> Any:
        """:meth:`_fit_core` of an untuned copy after the checks of ``fit``; returns the copy
        (with ``_fit_rows``, the number of rows it was fitted on)."""
        model = clone(self).set_params(tune=False)
        X, U = model._prepare_fit(X, U)
        model._fit_core(X, U, groups=groups, basis=basis, start=start, **fit_kw)
        model._fit_rows = len(U)  # a fit started from this one reads how many rows it saw
        return model

    def _cv_models(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds, *,
                   basis: Any = None, shared: dict[Any, Any] | None = None, **fit_kw: Any
                   ) -> tuple[Any, list[Any]]:
        """The models of this candidate's cross-validation (:func:`candidate_models`): one
        basis fitted on all of X (unless given; k-means sees no actions), the candidate
        fitted on all rows, and each training fold fitted starting from that fit (an
        iterative fit run to its tolerance from a start near its optimum; a closed-form
        learner overrides this with downdated normal equations and keeps them in ``shared``,
        the search's store, for its candidates on the same basis)."""
        basis = self._fit_basis(X, U) if basis is None else basis
        full = self._fit_given(X, U, groups=groups, basis=basis, **fit_kw)
        models = [self._fit_given(X[train], U[train], groups=groups[train], basis=basis, start=full,
                                  **take_rows(fit_kw, train))
                  for train, _ in folds.pairs]
        return full, models

    def _held_out_errors(self, models: list[Any], X: np.ndarray, U: np.ndarray, groups: np.ndarray,
                         folds: Folds, *, shared: dict[Any, Any] | None = None, **fit_kw: Any) -> np.ndarray:
        """The held-out errors of this candidate's fold ``models`` (n_folds,): :func:`held_out_errors`
        (a learner may use what its :meth:`_cv_models` kept in ``shared``)."""
        return held_out_errors(models, X, U, groups, folds, **fit_kw)

    def _fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None, **fit_kw: Any) -> Any:
        """The body of every learner's ``fit``: check the parameters and the data, then search
        (``tune``) or fit once, with one BLAS thread (with more, OpenBLAS's results depend on
        their number: eigh, solve and some products change in their last bits)."""
        X, U = self._prepare_fit(X, U)
        with blas.threads(1):
            if not self._fit_tuned(X, U, groups=groups, **fit_kw):
                self._fit_core(X, U, groups=groups, **fit_kw)
        return self

    def _fit_tuned(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None, **fit_kw: Any) -> bool:
        """Search and adopt the winner when ``tune`` is on; False (``tuning_ = None``) when
        there is nothing to tune and the caller fits as usual."""
        spec = self.tune
        opts = spec if isinstance(spec, dict) else {}
        grid = (opts.get("grid") or self._tune_grid(X, U)) if spec else {}
        self.tuning_ = None
        if not grid:
            return False
        search = Tuned(clone(self).set_params(tune=False), grid, folds=opts.get("folds"),
                       budget=opts.get("budget"), max_rows=opts.get("max_rows"), seed=int(self.seed))
        search.fit(X, U, groups=groups, **fit_kw)
        self._adopt(search.best_estimator_)
        self.tuning_ = search.tuning_
        return True


def _frozen(value: Any) -> Any:
    """A hashable stand-in for a parameter value: mappings and sequences as tuples, arrays by
    their shape and a digest of their bytes, callables and other objects by identity."""
    if isinstance(value, dict):
        return tuple(sorted((k, _frozen(v)) for k, v in value.items()))
    if isinstance(value, list | tuple):
        return tuple(_frozen(v) for v in value)
    if isinstance(value, np.ndarray):
        import hashlib

        data = np.ascontiguousarray(value)
        digest = hashlib.blake2b(data.view(np.uint8), digest_size=16).digest()
        return ("array", data.shape, str(data.dtype), digest)
    if isinstance(value, str | int | float | bool | type(None)):
        return value
    return ("object", id(value))


def rbf_tunable(basis: Any) -> bool:
    """Only a default RBF basis (a name or a dict without explicit centres/width) is tuned;
    a linear basis, a basis object or explicit centres/σ² are the user's choice."""
    if basis is None or basis == "rbf":
        return True
    return isinstance(basis, dict) and basis.get("kind", "rbf") == "rbf" and \
        "sigma2" not in basis and not isinstance(basis.get("centres"), list | np.ndarray)


def basis_grid(X: np.ndarray, sizes: tuple[int, ...], widths: tuple[float, ...], seed: int = 0,
               centres: str = "kmeans") -> list[dict[str, Any]]:
    """Candidate RBF bases (``basis`` parameter values): for each number of centres K
    (at most N/2; repeated values dropped) and width factor f, σ² = f · σ²_default(K)
    (the default rule of ALGORITHMS.md §2 on those centres; f = 1 is left to the rule)."""
    from ccl_cli.learn.basis import RBFBasis

    X = np.asarray(X, dtype=float)
    out: list[dict[str, Any]] = []
    for K in dict.fromkeys(int(k) for k in sizes):
        if K > max(1, len(X) // 2):
            continue
        s0 = RBFBasis(n_centres=K, centres=centres, seed=seed).fit(X).sigma2_ if any(
            f != 1 for f in widths) else 1.0
        for f in widths:
            spec: dict[str, Any] = {"kind": "rbf", "n_centres": int(K), "centres": centres}
            if f != 1:
                spec["sigma2"] = float(f * s0)
            out.append(spec)
    return out
