"""One cross-validation function over (estimator, X, U, groups): a clone of any learner fitted
on each training fold, its held-out error on the test fold — ``−estimator.score``, the learner's
own consistency error (:mod:`ccl_cli.learn.consistency`), never ground truth."""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass
from typing import Any

import numpy as np

from ccl_cli.learn.base import clone
from ccl_cli.learn.defaults import DEFAULT_GAP, N_FOLDS
from ccl_cli.learn.model_selection.splitters import Folds, make_folds


def take_rows(fit_kw: dict[str, Any], rows: np.ndarray) -> dict[str, Any]:
    """The arguments of ``fit`` for ``rows``: the per-sample ones (e.g. ``t`` (N,),
    ``projections`` (N, q, q)) cut to them, the others (``derivative``) as they are."""
    return {k: np.asarray(v)[rows] if v is not None and np.ndim(v) >= 1 else v for k, v in fit_kw.items()}


def held_out_error(model: Any, X: np.ndarray, U: np.ndarray, groups: np.ndarray, kw: dict[str, Any]) -> float:
    """A fitted learner's own consistency error on held-out data: its ``held_out_error`` when it
    has one (constraint models: NPOE — their ``score`` compares numbers of constraints instead),
    else −``score``."""
    if hasattr(model, "held_out_error"):
        return float(model.held_out_error(X, U, groups=groups, **kw))
    return -float(model.score(X, U, groups=groups, **kw))


def held_out_errors(models: list[Any], X: np.ndarray, U: np.ndarray, groups: np.ndarray, folds: Folds,
                    **fit_kw: Any) -> np.ndarray:
    """−model.score on each test fold (the learner's own consistency error), given the
    arguments of ``fit`` that its ``score`` takes too (``t``, ``projections``): (n_folds,)."""
    out = []
    for m, (_, test) in zip(models, folds.pairs, strict=True):  # a loop over the folds
        scored = {k: v for k, v in take_rows(fit_kw, test).items() if k in m._metadata("score")}
        out.append(held_out_error(m, X[test], U[test], groups[test], scored))
    return np.array(out, dtype=float)


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
            out.append(held_out_error(model, X[test], U[test], groups[test], extra))
    return CVResult(np.asarray(out, dtype=float), folds.kind, folds.reason)
