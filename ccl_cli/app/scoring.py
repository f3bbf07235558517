"""Scoring learnt models (ALGORITHMS.md §6): the numbers of every stage, of ``ccl evaluate``
and of the evaluate stage come from these functions, so one model gets one set of numbers.

Every number is an error of one model, named as in §6 (see docs/metrics.md), with its
normaliser computed from the data actually used and labelled by it (``normaliser_of``) and,
over several demonstrations or held-out time blocks, its standard error (``se``):

* constraint (learn-a): ``NPOE`` of the observations it was learnt from (u, or the learnt
  w̃ after a learn-v stage; minus the learnt task part Ã⁺b̃ when the model has one) and,
  with ground truth, ``NPPE``;
* null-space component (learn-v): ``NPE`` and, with ground truth, ``NUPE_w`` / ``NUPE_v``;
* policy (learn-pi): with ground truth ``NUPE`` and ``NCPE``; with a learnt constraint
  ``NCPE_obs`` (observations against Ñπ̃).

``convention="original"`` switches to the original library's normalisers (NPPE and NPOE:
var(π) for state-independent models, var of the true w for state-dependent ones; NPE:
ddof = 0).

A constraint is scored as it applies to the data (:meth:`applied_on`: the model's own stated
rule for data it has not seen, :class:`~ccl_cli.learn.constraint.base.Applied`); nothing here
fits a model.
"""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli import metrics
from ccl_cli.dataset import Demonstrations
from ccl_cli.learn.consistency import apply_projection
from ccl_cli.learn.constraint.base import Applied, ConstraintModel

KINDS = {"learn-a": "constraint", "learn-v": "nullspace", "learn-pi": "policy"}


def _dict(*items: metrics.Metric) -> dict[str, dict]:
    return {m.name: m.as_dict() for m in items}


def applied_on(model: Any, d: Demonstrations, Y: np.ndarray, new_data: bool = False) -> Applied:
    """A constraint model as it applies to ``d`` with observations ``Y`` (N, q): by its own
    stated rule (:meth:`~ccl_cli.learn.constraint.base.ConstraintModel.applies_to`) — as fitted,
    or, for a model per stretch on demonstrations it has not seen (any, with ``new_data``: a saved
    model on a recording), fitted on ``d`` as the rule says, with the note saying so."""
    return model.applies_to(d.X, Y, groups=d.demo, t=d.t, new_recording=new_data)


def projection_on(applied: Applied, d: Demonstrations, per_sample: bool = True) -> np.ndarray:
    """Ñ (N, q, q) of an applied constraint model at the samples of ``d``; with
    ``per_sample=False`` one (q, q) when the model's Ã is one constant matrix that holds at every
    sample (:meth:`~ccl_cli.learn.constraint.base.ConstraintModel.constant_rows`, ``holds`` not
    restricted to stretches): its projection at the first sample, N × q² floats fewer (a metric
    applies either)."""
    model = applied.model.chosen_
    if not per_sample and d.n_samples and model.constant_rows() is not None \
            and type(model).holds is ConstraintModel.holds:
        return applied.model.projection(d.X[:1], groups=d.demo[:1], t=d.t[:1])[0]
    return applied.model.projection(d.X, groups=d.demo, t=d.t)


def task_part(applied: Applied, d: Demonstrations) -> np.ndarray | None:
    """The learnt task part ṽ = Ã⁺ b̃ (§1) of an applied constraint model with a task term at the
    samples of ``d``: (N, q), or ``None`` when the model has none (then ṽ = 0)."""
    return applied.model.task_part(d.X, groups=d.demo, t=d.t)


def _has_true_constraint(d: Demonstrations) -> bool:
    return d.has_truth("pi") and (d.has_truth("N") or d.has_truth("A"))


def groups_of(d: Demonstrations) -> np.ndarray:
    """Ids of the contiguous pieces of ``d`` that the spread of a figure is taken over: each
    demonstration, and inside one, each run of samples without a time gap (the held-out time
    blocks of a continuous recording; a gap is over 5 median sampling intervals): (N,). Computed
    once per data (:meth:`~ccl_cli.dataset.Demonstrations.memo`: every figure of a part reads it)."""
    return d.memo("groups_of", lambda: _pieces(d))


def _pieces(d: Demonstrations) -> np.ndarray:
    n = d.n_samples
    if n < 2:
        return np.zeros(n, dtype=int)
    dt = np.diff(d.t)
    same = d.demo[1:] == d.demo[:-1]
    step = np.median(dt[same & (dt > 0)]) if np.any(same & (dt > 0)) else 0.0
    cut = ~same | (dt > 5 * step if step > 0 else dt < 0)
    return np.r_[0, np.cumsum(cut)]


def constraint_metrics(applied: Applied, d: Demonstrations, Y: np.ndarray, convention: str = "ccl",
                       of: str = "u") -> dict[str, dict]:
    """NPOE of the observations ``Y`` (N, q) the model was learnt from (``of`` names them)
    and, with ground truth π and N, NPPE; both under ``convention``, of the constraint model as
    it applies to ``d`` (:func:`applied_on`; its note, when it was fitted there, goes into every
    entry)."""
    N_est, note = projection_on(applied, d, per_sample=False), applied.note
    sd = applied.model.varies_with_state
    truth = _has_true_constraint(d)
    Pi = d.truth["pi"] if truth else None
    W = None
    if truth and sd:
        W = d.truth["w"] if d.has_truth("w") else apply_projection(d.true_projection(False), Pi)
    groups = groups_of(d)
    items = [metrics.npoe(N_est, Y, convention, Pi=None if sd else Pi, W=W,
                          V_est=task_part(applied, d), of=of, groups=groups)]
    if truth:
        items.append(metrics.nppe(d.true_projection(False), N_est, Pi, d.U, convention, state_dependent=sd,
                                  groups=groups))
    out = _dict(*items)
    for entry in out.values() if note else ():
        entry["note"] = note
    return out


def nullspace_metrics(w: np.ndarray, d: Demonstrations, convention: str = "ccl", truth: bool = True
                      ) -> dict[str, dict]:
    """NPE of the learnt w̃ (N, q) and, with ground truth (unless ``truth=False``), NUPE of w and
    of v = u − w̃."""
    groups = groups_of(d)
    items = [metrics.npe(d.U, w, convention, groups)]
    if truth and d.has_truth("w"):
        items.append(metrics.nupe(d.truth["w"], w, "NUPE_w", "w", groups))
    if truth and d.has_truth("v"):
        items.append(metrics.nupe(d.truth["v"], d.U - w, "NUPE_v", "v", groups))
    return _dict(*items)


def policy_metrics(est: np.ndarray, d: Demonstrations, constraint: Applied | None = None,
                   Y: np.ndarray | None = None, of: str = "u") -> dict[str, dict]:
    """With ground truth: NUPE and NCPE of π̃ (N, q). With a learnt ``constraint`` as it applies
    to ``d`` (:func:`applied_on`, with the observations ``Y`` it was learnt from): NCPE_obs, the
    observations against Ñπ̃."""
    items = []
    groups = groups_of(d)
    if d.has_truth("pi"):
        items.append(metrics.nupe(d.truth["pi"], est, groups=groups))
        if _has_true_constraint(d):
            items.append(metrics.ncpe(d.true_projection(False), d.truth["pi"], est, groups))
    if constraint is not None:
        Y = d.U if Y is None else Y
        N_est = projection_on(constraint, d, per_sample=False)
        items.append(metrics.ncpe_observed(N_est, Y, est, task_part(constraint, d), of, groups))
    return _dict(*items)
