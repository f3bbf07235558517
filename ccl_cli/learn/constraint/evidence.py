"""Held-out evidence for the candidates of learn-a's ``auto`` (:mod:`.auto`): each candidate's
rows at samples it did not see, its rank by the noise rule on them, and its held-out NPOE.

Shapes: X (N, p), U (N, q), groups (N,) demonstration ids, t (N,) seconds; rows (N, m, q): the
first m rows of the model fitted without each sample, at that sample.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.learn import model_selection as ms
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.base import ConstraintModel
from ccl_cli.learn.linalg import nullspace_projection

#: The data of one fit and how its actions were made (:class:`.noise_rank.Sample`).
Sample = nr.Sample


@dataclass
class Candidate:
    """A model class of ``auto``: its name, a phrase for the report, a maker of the estimator
    with k rows, the most rows it can have, and — for a model per stretch (window or
    demonstration) — the stretch of each sample (held-out blocks inside them) and its name."""

    name: str
    label: str
    make: Callable[[int], ConstraintModel]
    max_rows: int
    segments: np.ndarray | None = None
    what: str = ""


def standard_error(errors: np.ndarray) -> float:
    """Standard error of the mean of per-fold errors (0 for one fold)."""
    return float(errors.std(ddof=1) / np.sqrt(len(errors))) if len(errors) > 1 else 0.0


@dataclass
class Tried:
    """What the cross-validation found for one candidate: on its own ``folds``, its held-out
    ``rows``, its rank ``k`` (None: the fits failed, ``note`` says why) and the ``evidence`` the
    rank read; then its held-out NPOE per fold with the rows that decide (``errors``), on the
    folds every candidate of that rank is compared on (``scored_on``)."""

    candidate: Candidate
    folds: ms.Folds
    rows: np.ndarray | None = None
    k: int | None = None
    evidence: nr.RowEvidence | None = None
    rank_reason: str = ""
    errors: np.ndarray | None = None
    scored_on: ms.Folds | None = None
    note: str = ""
    extra: dict[str, Any] = field(default_factory=dict)  # further entries of its table row

    @property
    def mean(self) -> float:
        return float(self.errors.mean())

    @property
    def se(self) -> float:
        return standard_error(self.errors)

    def limits(self) -> dict[str, Any]:
        """The noise rule's limits for its rows (:func:`.noise_rank.row_limits`, as :func:`rank`
        applies them): ``noise_limit`` and ``share_limit`` per row (None: a row only its noise
        ratio can admit), both None when the rule could not judge — then ``ratio_limit``: the
        ratio rule's limit on each row's share (:func:`.rank.ratio_limits`, None for row 1)."""
        ev = self.evidence
        if ev is None:
            return {"noise_limit": None, "share_limit": None}
        if not ev.snr >= nr.MIN_SNR:  # the ratio rule on the held-out energies, as shares
            return {"noise_limit": None, "share_limit": None, "ratio_limit": sel.ratio_limits(ev.share)}
        limit, share = nr.row_limits(ev.ratio, share_rows=nr.SHARE_ROWS)
        return {"noise_limit": [float(v) for v in limit],
                "share_limit": [float(v) if np.isfinite(v) else None for v in share]}

    def row(self, chosen: bool, reason: str) -> dict[str, Any]:
        """The candidate as a row of the report's table."""
        ev = self.evidence
        return {"class": self.candidate.name, "model": self.candidate.label, "k": self.k,
                "error": "held-out NPOE", "heldout_error": None if self.errors is None else self.mean,
                "se": None if self.errors is None else self.se,
                "noise_ratio": None if ev is None else [float(v) for v in ev.ratio],
                "share": None if ev is None else [float(v) for v in ev.share],
                **self.limits(), "folds": self.folds.reason, "rank_reason": self.rank_reason,
                "scored_on": None if self.scored_on is None else self.scored_on.reason, "chosen": chosen,
                "reason": reason, **self.extra}


def not_tried(name: str, why: str) -> dict[str, Any]:
    """The table row of a candidate that was not tried."""
    return {"class": name, "model": name, "k": None, "error": "held-out NPOE", "heldout_error": None,
            "se": None, "noise_ratio": None, "share": None, "noise_limit": None, "share_limit": None,
            "folds": None, "rank_reason": "",
            "scored_on": None, "chosen": False, "reason": f"not tried: {why}"}


def held_out_rows(cand: Candidate, folds: ms.Folds, m: int, data: Sample) -> np.ndarray:
    """The first m rows of the candidate fitted on each training fold, at that fold's held-out
    samples: (N, m, q). A model per stretch has no rows for a demonstration its training fold
    holds no sample of (one too short for blocks inside it): those samples take the rows of the
    same kind of model fitted on the whole training fold as one stretch — still not fitted on them."""
    X, U, g, t = data.X, data.U, data.groups, data.t
    rows = np.zeros((len(U), m, U.shape[1]))
    for train, test in folds.pairs:
        at = (lambda idx: None) if t is None else (lambda idx: t[idx])
        model = cand.make(m).fit(X[train], U[train], groups=g[train], t=at(train))
        seen = np.isin(g[test], g[train]) if model.is_local else np.ones(len(test), dtype=bool)
        if seen.any():
            rows[test[seen]] = model.constraint(X[test[seen]], groups=g[test[seen]], t=at(test[seen]))[:, :m]
        if not seen.all():
            one = np.zeros(len(train), np.int64)
            pooled = cand.make(m).fit(X[train], U[train], groups=one, t=at(train))
            orphan = test[~seen]
            rows[orphan] = pooled.constraint(X[orphan], groups=np.zeros(len(orphan), np.int64),
                                             t=at(orphan))[:, :m]
    return rows


def pieces(folds: ms.Folds, groups: np.ndarray) -> np.ndarray:
    """An id per sample of each contiguous held-out stretch (a run of one fold's samples within
    one demonstration): second differences never straddle two stretches."""
    fold = np.full(len(groups), -1)
    for j, (_, test) in enumerate(folds.pairs):
        fold[test] = j
    return np.cumsum(np.r_[True, (fold[1:] != fold[:-1]) | (groups[1:] != groups[:-1])])


def rank(tried: Tried, m: int, data: Sample) -> None:
    """k of a candidate by the noise rule on its held-out rows, or — when the samples are not
    trajectories it can judge — the ratio rule on the held-out energies (k ≥ 1)."""
    ev = data.rows_evidence(tried.rows, pieces(tried.folds, data.groups))
    tried.evidence = ev
    chosen = nr.noise_rank(ev, m, share_rows=nr.SHARE_ROWS)
    if chosen is None:  # on the shares (the energies over one total): the same rows count
        chosen = sel.ratio(ev.share, m, criterion="held-out energy along row k")
        chosen.reason = ("the samples are not trajectories the noise rule can judge (total variance "
                         f"< {nr.MIN_SNR:g} × noise): ratio rule on held-out energies; " + chosen.reason)
    tried.k = int(chosen.n_constraints)
    tried.rank_reason = chosen.reason


def cap_local(tried: list[Tried]) -> None:
    """A model per window (or per demonstration) calls every direction its stretch happened not
    to move along a constraint — within a short stretch the motion often takes fewer than
    q − k directions. It may claim no more rows than the best global model, or one when no
    global model finds any (a constraint that changes from one stretch to the next)."""
    k_global = max([c.k for c in tried if c.candidate.segments is None and c.k is not None], default=0)
    cap = max(k_global, 1)
    for c in tried:
        if c.candidate.segments is not None and c.k is not None and c.k > cap:
            c.rank_reason += (f"; capped at {cap}: more rows per {c.candidate.what} than any global model "
                              "finds are directions its stretches did not explore")
            c.k = cap


def score(tried: Tried, k: int, data: Sample, folds: ms.Folds | None = None) -> None:
    """Held-out NPOE per fold of the candidate with k rows (``errors``), on ``folds`` (None: its
    own; others: the candidate is fitted again on their training parts) → ``scored_on``."""
    folds = folds or tried.folds
    rows = tried.rows if folds is tried.folds else held_out_rows(tried.candidate, folds, max(k, 1), data)
    tried.errors = np.array([npoe_error(nullspace_projection(rows[test, :k]), data.U[test]) if k else 0.0
                             for _, test in folds.pairs])
    tried.scored_on = folds


def within_one_se(c: Tried, best: Tried) -> bool:
    """Whether ``c``'s mean held-out NPOE is within one standard error of the best's, both scored
    on the same folds: the standard error of their per-fold differences (a paired comparison)."""
    diff = c.errors - best.errors
    return float(diff.mean()) <= standard_error(diff)
