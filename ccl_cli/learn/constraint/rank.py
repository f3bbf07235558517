"""Choosing the number of constraints s (ALGORITHMS.md §3.4).

Every rule returns a :class:`Selection` recording the rule, the chosen number, the
criterion it looked at for each candidate k = 1..max_k, and a sentence saying why, so a
report can tabulate and plot it. ``model.selection_`` is :meth:`Selection.as_dict`::

    {"rule": str, "n_constraints": int,
     "values": [criterion for k = 1, 2, ...],   # what the rule compared (see below)
     "criterion": str,                          # what "values" are
     "reason": str,
     "limits": [the rule's limit on value k, or None],   # where the rule has limits (below)
     "limit_rule": str}                         # how a value is held against its limit

``limits`` and ``limit_rule`` let a figure draw each candidate against the rule: ``ratio``
(the value of row k at most RATIO_FACTOR × row 1's), ``threshold`` (below the level),
``cv`` (the held-out NPOE of k rows at most that of k − 1 rows + RATIO_FACTOR × row 1's
increment + one SE), ``noise`` (:mod:`.noise_rank`: also ``share`` and ``share_limits``);
``eigengap`` has none (the largest gap decides: ``gaps``), nor ``fixed``.

Each learner has a sequence of residuals ρ_1 ≤ ρ_2 ≤ ... of its candidate constraint
rows (nhat: eigenvalues of Σ u uᵀ / N; alpha, lambda: nmse of row k; linear: squared
singular values of the scaled regressors); the rules read it:

* ``ratio`` (the default, :data:`DEFAULT_RULE`) — the noise-aware threshold: row 1 is
  always a constraint, so ρ_1 is the noise level of the data in that direction; row k is
  kept while ρ_k ≤ :data:`RATIO_FACTOR` · ρ_1 (values floored at ``floor · max ρ`` so the
  exact zeros of noise-free data count as equal). A direction the demonstrations move
  along carries the motion on top of the noise; a constraint direction carries only noise.
* ``threshold`` — the original library's rule for the learner at hand;
* ``eigengap`` — the largest ratio between consecutive residuals;
* ``cv`` — held-out NPOE by cross-validation (:func:`ccl_cli.learn.model_selection.cross_validate`):
  the held-out energy Δ_k removed by row k, kept while Δ_k is within one standard error
  (paired over folds) of RATIO_FACTOR · Δ_1;
* ``noise`` (lambda's default) — the noise-aware test of
  :mod:`ccl_cli.learn.constraint.noise_rank` on the learnt rows: row k is a constraint when the
  motion along it is at the noise level the second differences of the trajectories show
  (the sample times and how the actions were made, when ``fit`` is given them); on samples
  that are not trajectories it cannot judge and ``ratio`` decides. An explicit learner keeps
  at least one row (k = 0 is ``auto``'s answer);
* ``fixed`` — the user's number.

Chosen on evidence (``benchmarks/bench_rank.py``): see README "Number of constraints".
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any, get_args

import numpy as np

from ccl_cli.errors import ConfigError
from ccl_cli.learn import model_selection
from ccl_cli.learn.base import clone
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.defaults import DEFAULT_RULE, RATIO_FACTOR
from ccl_cli.learn.params import (
    Interval,
    MaxConstraints,
    NConstraints,
    NFolds,
    NonNegative,
    out_of_range,
    parameters,
)
from ccl_cli.learn.params import SelectionRule as Rule

#: The rules a learner's ``selection`` may name; "fixed" is recorded when ``n_constraints`` is given.
RULES = (*get_args(Rule), "fixed")
__all__ = ["DEFAULT_RULE", "RATIO_FACTOR", "RULES", "Rule", "Selection"]


@parameters
class SelectionParams:
    """How the number of constraints s is chosen: ``selection`` (``ratio``, the noise-aware
    default; ``threshold``, the original; ``eigengap``; ``cv``), or fixed by ``n_constraints``;
    at most ``max_constraints`` rows (default q − 1); ``gap_floor``: the relative floor of the
    residuals; ``cv_folds``: folds of the ``cv`` rule."""

    selection: Rule = DEFAULT_RULE
    n_constraints: NConstraints = None
    max_constraints: MaxConstraints = None
    gap_floor: NonNegative = 1e-9
    cv_folds: NFolds = 5


@parameters
class ThresholdParams:
    """``threshold``: the level of the ``threshold`` rule (original: 0.1)."""

    threshold: NonNegative = 0.1


@dataclass
class Selection:
    """How k was chosen (module docstring): ``limits`` (per value, None where the rule sets
    none) and ``limit_rule`` (in words) when the rule compares values with limits; ``extra``
    further evidence of the rule (entries of :meth:`as_dict`)."""

    rule: str
    n_constraints: int
    values: list[float] = field(default_factory=list)
    reason: str = ""
    criterion: str = ""
    limits: list[float | None] | None = None
    limit_rule: str = ""
    extra: dict[str, Any] = field(default_factory=dict)

    def as_dict(self) -> dict:
        out = {"rule": self.rule, "n_constraints": self.n_constraints,
               "values": [float(v) for v in self.values], "criterion": self.criterion,
               "reason": self.reason}
        if self.limits is not None:
            out["limits"] = finite_or_none(self.limits)
            out["limit_rule"] = self.limit_rule
        return {**out, **self.extra}


def finite_or_none(values: Any) -> list[float | None]:
    """Floats of ``values`` (m,), None where a value is None or not finite (JSON has no inf)."""
    return [None if v is None or not np.isfinite(v) else float(v) for v in values]


def rule_of(model: Any) -> str:
    """The rule a learner applies: "fixed" when its ``n_constraints`` is given, else its ``selection``."""
    return "fixed" if model.n_constraints is not None else model.selection


def choose(model: Any, *, ratio_values: np.ndarray, gap_values: np.ndarray, max_k: int, fixed_max: int,
           criterion: str, threshold: Callable[[], Selection], X: np.ndarray, U: np.ndarray,
           groups: np.ndarray | None, noise: Callable[[], Selection | None] | None = None) -> Selection:
    """s by the learner's rule (:func:`rule_of`): ``fixed`` (1..fixed_max), ``threshold``
    (the learner's own, ``threshold()``), ``eigengap`` on ``gap_values``, ``ratio`` on
    ``ratio_values`` (``criterion`` names them), ``noise`` by ``noise()`` (None: it cannot
    judge, or the learner has no such test: ``ratio``), ``cv`` by :func:`cross_validated` on X, U."""
    rule = rule_of(model)
    if rule == "fixed":
        return fixed(model.n_constraints, fixed_max)
    if rule == "threshold":
        return threshold()
    if rule == "eigengap":
        return gap(gap_values, model.gap_floor)
    if rule == "noise":
        chosen = noise() if noise is not None else None
        if chosen is None:
            chosen = ratio(ratio_values, max_k, model.gap_floor, criterion=criterion)
            chosen.reason = ("the noise test cannot judge these samples (not trajectories in time, or "
                             "this learner has none): " + chosen.reason)
        elif chosen.n_constraints == 0:
            chosen.n_constraints = 1
            chosen.reason += "; one row kept (method auto may answer no constraint)"
        return chosen
    if rule == "ratio":
        return ratio(ratio_values, max_k, model.gap_floor, criterion=criterion)
    return cross_validated(model, X, U, groups, max_k, model.cv_folds, model.seed)


#: How a ``threshold`` rule on nmse holds its values (``.format(threshold)``).
THRESHOLD_RULE = "row k counts while its nmse is below {:g} (the original's rule; row 1 always counts)"


def threshold_limits(m: int, threshold: float) -> list[float | None]:
    """The limits of the original's threshold rule for m candidate rows: none for row 1, then
    ``threshold``."""
    return [None] + [float(threshold)] * max(m - 1, 0)


def fixed(n: int, max_k: int) -> Selection:
    if not 1 <= n <= max_k:
        raise ConfigError(out_of_range("n_constraints", n, Interval(1, max_k, type=int)))
    return Selection("fixed", n, [], f"fixed by the user at {n}")


def gap(values: np.ndarray, floor: float = 1e-9, rule: str = "eigengap") -> Selection:
    """s = argmax_k v_{k+1} / v_k over ascending values v_1..v_m (k = 1..m−1)."""
    v = np.asarray(values, dtype=float)
    if v.size < 2:
        return Selection(rule, 1, list(v), "only one candidate")
    top = max(float(np.max(v)), np.finfo(float).tiny)
    vf = np.maximum(v, floor * top)
    ratios = vf[1:] / vf[:-1]
    k = int(np.argmax(ratios)) + 1
    return Selection(rule, k, list(v),
                     f"largest gap between residual {k} and {k + 1} (ratio {ratios[k - 1]:.3g})",
                     extra={"gaps": finite_or_none(ratios)})


def ratio(values: np.ndarray, max_k: int, floor: float = 1e-9, factor: float = RATIO_FACTOR,
          criterion: str = "residual") -> Selection:
    """Noise-aware threshold: s = the number of leading residuals ρ_k ≤ factor · ρ_1
    (ρ floored at ``floor · max ρ``), at least 1 and at most ``max_k``.

    ``values`` may hold one more candidate than ``max_k`` (it is shown, not chosen).
    """
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        raise ConfigError("no candidate constraints to choose from")
    limits = ratio_limits(v, floor, factor)
    top = max(float(np.max(v)), np.finfo(float).tiny)
    vf = np.maximum(v, floor * top)
    k = 1
    while k < min(max_k, v.size) and vf[k] <= limits[k]:
        k += 1
    if k < v.size:
        why = (f"row {k + 1} has {vf[k] / vf[0]:.3g}× the residual of row 1 (> {factor:g}: "
               "motion, not noise)")
    else:
        why = f"all {k} candidates within {factor:g}× the residual of row 1 (noise level)"
    return Selection("ratio", k, list(v), why, criterion, limits,
                     f"row k counts while its value is at most {factor:g}× row 1's (row 1 always counts)")


def ratio_limits(values: Any, floor: float = 1e-9, factor: float = RATIO_FACTOR) -> list[float | None]:
    """The limit :func:`ratio` holds each of ``values`` (m,) against: none for row 1 (always a
    constraint), then ``factor`` × row 1's value (floored at ``floor`` × the largest)."""
    v = np.asarray(values, dtype=float)
    if v.size == 0:
        return []
    top = max(float(np.max(v)), np.finfo(float).tiny)
    return [None] + [factor * max(float(v[0]), floor * top)] * (v.size - 1)


def cv_rule(increments: np.ndarray, max_k: int, factor: float = RATIO_FACTOR) -> Selection:
    """One-standard-error rule on held-out energies.

    ``increments`` (n_folds, m): per fold, the held-out NPOE added by row k (Δ_k =
    NPOE_k − NPOE_{k−1}). Row k is kept while mean(Δ_k − factor·Δ_1) ≤ its standard
    error over the folds.
    """
    inc = np.asarray(increments, dtype=float)
    n_folds = inc.shape[0]
    mean = inc.mean(0)
    total = np.cumsum(mean)
    limits: list[float | None] = [None]  # on the held-out NPOE of k rows, total[k - 1]
    within = []
    for j in range(1, inc.shape[1]):
        diff = inc[:, j] - factor * inc[:, 0]
        se = diff.std(ddof=1) / np.sqrt(n_folds) if n_folds > 1 else 0.0
        limits.append(float(total[j - 1] + factor * mean[0] + se))
        within.append(diff.mean() <= se)
    k = 1
    while k < min(max_k, inc.shape[1]) and within[k - 1]:
        k += 1
    why = (f"row {k + 1} removes {mean[k] / max(mean[0], 1e-300):.3g}× the held-out energy of row 1 "
           f"(more than {factor:g}× + 1 SE)" if k < inc.shape[1]
           else f"all {k} rows remove held-out energy at the noise level")
    return Selection("cv", k, list(total), why, "held-out NPOE of the first k rows", limits,
                     f"k rows count while the held-out NPOE of k rows is at most that of k − 1 rows + "
                     f"{factor:g}× row 1's + one SE over the folds")


def truncated_npoe(model: Any, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None = None) -> np.ndarray:
    """Held-out NPOE of the model's first k rows, k = 1..n_constraints_ (nested learners): (m,)."""
    return np.array([npoe_error(model.projection_k(X, k), U) for k in range(1, model.n_constraints_ + 1)])


def cross_validated(model: Any, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None, max_k: int,
                    n_folds: int = 5, seed: int = 0, factor: float = RATIO_FACTOR) -> Selection:
    """The ``cv`` rule for any nested constraint learner (one with ``projection_k``): a
    clone with ``max_k`` rows is fitted per training fold by
    :func:`ccl_cli.learn.model_selection.cross_validate` and the held-out NPOE of its first k rows,
    k = 1..max_k, is read on the test fold (the data the learner was given: joint-space
    actions for lambda, not the task-space ones it fits its selection on)."""
    est = clone(model).set_params(n_constraints=max_k)
    res = model_selection.cross_validate(est, X, U, groups, n_folds=n_folds, seed=seed, scorer=truncated_npoe)
    npoe = res.errors
    inc = np.diff(np.concatenate([np.zeros((npoe.shape[0], 1)), npoe], 1), axis=1)
    chosen = cv_rule(inc, max_k, factor)
    chosen.reason += f"; {res.reason}"
    return chosen
