"""The hyperparameter search: a grid searched by cross-validation within a budget counted in
model fits (candidates × folds), never in seconds, so the same data and settings give the same
model on any machine at any load — and :class:`Tuned`, the search as an estimator.

The search costs a few fits: a candidate's folds share work (a closed-form learner's normal
equations are summed once and downdated per fold; an iterative learner's folds start from its
fit of all rows, seen through each fold's rows — a :class:`Searchable` learner says how),
candidates on one basis share it, the grid runs from the smallest basis up and stops where a
larger one does not help, and large data are searched on a seeded subset. scikit-learn's
``GridSearchCV`` refits every candidate on every fold from scratch and has no budget or early
stop: it does a different job (docs/internals.md, "Model selection").
"""

from __future__ import annotations

import itertools
from dataclasses import dataclass
from typing import Annotated, Any, ClassVar

import numpy as np

from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.learn import blas
from ccl_cli.learn.base import Estimator, check_xu, clone
from ccl_cli.learn.defaults import DEFAULT_GAP, N_FOLDS, TUNE_BUDGET, TUNE_FOLDS
from ccl_cli.learn.model_selection.splitters import Folds, make_folds, tuning_subset
from ccl_cli.learn.model_selection.validation import held_out_errors, take_rows
from ccl_cli.learn.params import Interval, NFolds, Seed
from ccl_cli.progress import progress_of

#: What ``budget`` and ``budget_used`` count.
BUDGET_UNIT = "fits (candidates × folds)"
#: A search's budget: model fits (candidates × folds); its rows at most.
Budget = Annotated[float, Interval(0, None)]
MaxRows = Annotated[int, Interval(100, None)]


class Searchable:
    """A learner that shares work across a search (:class:`~.tuning.Tunable` implements it): one
    fitted basis for the candidates with equal basis settings (:meth:`_basis_key`,
    :meth:`_fit_basis`), the models of one candidate's cross-validation (:meth:`_cv_models`),
    their held-out errors (:meth:`_held_out_errors`) and a fit given a basis and a start
    (:meth:`_fit_given`). These parts read, of the arguments of ``fit`` beside ``groups``,
    only those in :attr:`FIT_DATA` (:meth:`_fit_data`). Any other learner is cloned and
    fitted per fold."""

    #: The arguments of ``fit`` beside ``groups`` the fit in parts reads (e.g. ``projections``).
    FIT_DATA: ClassVar[tuple[str, ...]] = ()

    def _fit_data(self, fit_kw: dict[str, Any]) -> dict[str, Any]:
        """Of ``fit_kw``, those :attr:`FIT_DATA` names (``t`` and ``derivative``, which every learner
        takes, are not read by a search's fits)."""
        return {k: v for k, v in fit_kw.items() if k in self.FIT_DATA}

    def _basis_key(self) -> tuple:
        raise NotImplementedError

    def _fit_basis(self, X: np.ndarray, U: np.ndarray) -> Any:
        raise NotImplementedError

    def _cv_models(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds, *,
                   basis: Any = None, shared: dict[Any, Any] | None = None, **fit_kw: Any
                   ) -> tuple[Any, list[Any]]:
        raise NotImplementedError

    def _held_out_errors(self, models: list[Any], X: np.ndarray, U: np.ndarray, groups: np.ndarray,
                         folds: Folds, *, shared: dict[Any, Any] | None = None, **fit_kw: Any) -> np.ndarray:
        raise NotImplementedError

    def _fit_given(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None, basis: Any = None,
                   start: Any = None, **fit_kw: Any) -> Any:
        raise NotImplementedError


def candidate_models(estimator: Any, X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds,
                     basis: Any = None, shared: dict[Any, Any] | None = None, **fit_kw: Any
                     ) -> tuple[Any | None, list[Any]]:
    """The models one candidate's cross-validation needs: (the candidate fitted on all of X
    (N, p), U (N, q), or None; one model per training fold of ``folds``).

    A :class:`Searchable` learner shares work between them (:meth:`Searchable._cv_models`: one
    basis, normal equations downdated per fold, folds started from the all-rows fit);
    any other estimator is cloned and fitted per fold. ``basis``: a fitted feature map
    to use (Searchable learners only; None: fitted on X); ``shared``: a store the search keeps for
    its candidates on the same data and folds (e.g. normal equations of a basis)."""
    if isinstance(estimator, Searchable):
        return estimator._cv_models(X, U, groups, folds, basis=basis, shared=shared,
                                    **estimator._fit_data(fit_kw))
    models = [clone(estimator).fit(X[train], U[train], groups=groups[train], **take_rows(fit_kw, train))
              for train, _ in folds.pairs]
    return None, models


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
                if isinstance(candidate, Searchable):  # one fitted basis per distinct basis setting
                    key = candidate._basis_key()
                    if key not in bases:
                        bases[key] = candidate._fit_basis(*(basis_data or (X, U)))
                    basis = bases[key]
                full, models = candidate_models(candidate, X, U, groups, folds, basis, shared, **fit_kw)
                if isinstance(candidate, Searchable):
                    errors = candidate._held_out_errors(models, X, U, groups, folds, shared=shared,
                                                        **candidate._fit_data(fit_kw))
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
            :data:`TUNE_MAX_ROWS`); the winner is fitted on all (a :class:`Searchable` learner
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
            elif found is not None and isinstance(winner, Searchable):
                self.best_estimator_ = winner._fit_given(X, U, groups=groups, basis=found.basis,
                                                         start=found.full, **winner._fit_data(fit_kw))
            else:
                self.best_estimator_ = winner.fit(X, U, groups=groups, **fit_kw)
        self.best_params_ = chosen
        self.best_score_ = -min((r["mean"] for r in self.tuning_.get("scores", [])), default=np.nan)
        if hasattr(self.best_estimator_, "n_features_in_"):
            self.n_features_in_ = self.best_estimator_.n_features_in_
        return self

    def _metadata(self, method: str) -> tuple[str, ...]:
        """What ``fit`` / ``score`` pass on: the estimator's (and ``groups``, the search's folds)."""
        inner = self.estimator._metadata(method)
        return inner if method != "fit" or "groups" in inner else ("groups", *inner)

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

    @property
    def chosen_(self) -> Any:
        """The winner, fitted on all the data."""
        return self._best()

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """The winner's Ñ(X): (N, p) → (N, q, q)."""
        return self._best().projection(X, groups=groups, t=t)

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """The winner's Ã(X): (N, p) → (N, s, q)."""
        return self._best().constraint(X, groups=groups, t=t)

    def score(self, X: np.ndarray, U: np.ndarray, **kw: Any) -> float:
        """The winner's score (higher is better)."""
        return self._best().score(X, U, **kw)

    def held_out_error(self, X: np.ndarray, U: np.ndarray, **kw: Any) -> float:
        """The winner's own consistency error (its ``held_out_error``, else −score)."""
        best = self._best()
        return best.held_out_error(X, U, **kw) if hasattr(best, "held_out_error") else -best.score(X, U, **kw)
