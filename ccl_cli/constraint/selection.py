"""Choosing the number of constraints s (ALGORITHMS.md §3.4).

Every rule returns a :class:`Selection` recording the rule, the chosen number, the
numbers it was chosen from, and a sentence saying why, so a report can show it.

* ``threshold`` — the original library's rule for the learner at hand;
* ``eigengap`` — the largest ratio between consecutive residuals (ascending), each
  floored at ``floor · largest`` so exact zeros of noise-free data do not win;
* ``cv`` — the same gap rule on the held-out NPOE of each candidate count,
  cross-validated over demonstrations;
* ``fixed`` — the user's number.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field

import numpy as np

from ccl_cli.errors import ConfigError, InputError

RULES = ("threshold", "eigengap", "cv", "fixed")


@dataclass
class Selection:
    rule: str
    n_constraints: int
    values: list[float] = field(default_factory=list)
    reason: str = ""

    def as_dict(self) -> dict:
        return {"rule": self.rule, "n_constraints": self.n_constraints,
                "values": [float(v) for v in self.values], "reason": self.reason}


def check_rule(rule: str, n_constraints: int | None) -> str:
    if n_constraints is not None:
        return "fixed"
    if rule not in RULES:
        raise ConfigError(f"unknown constraint-count rule {rule!r} (use {', '.join(RULES)})")
    if rule == "fixed":
        raise ConfigError("selection 'fixed' needs n_constraints")
    return rule


def fixed(n: int, max_k: int) -> Selection:
    if not 1 <= n <= max_k:
        raise ConfigError(f"n_constraints must be between 1 and {max_k}, got {n}")
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
                     f"largest gap between residual {k} and {k + 1} (ratio {ratios[k - 1]:.3g})")


def demo_folds(demo: np.ndarray, n_folds: int, seed: int) -> list[np.ndarray]:
    """Boolean test masks of ``n_folds`` folds over demonstrations (or over
    contiguous blocks of samples when there is only one demonstration)."""
    ids = np.unique(demo)
    rng = np.random.default_rng(seed)
    if len(ids) >= 2:
        n_folds = min(n_folds, len(ids))
        perm = rng.permutation(ids)
        return [np.isin(demo, part) for part in np.array_split(perm, n_folds)]
    n = len(demo)
    if n < 2 * n_folds:
        raise InputError(f"cross-validation needs at least {2 * n_folds} samples, got {n}")
    blocks = np.array_split(np.arange(n), n_folds)
    return [np.isin(np.arange(n), b) for b in blocks]


def cross_validated(
    fit_candidates: Callable[[np.ndarray], Callable[[np.ndarray, int], np.ndarray]],
    U: np.ndarray,
    demo: np.ndarray,
    max_k: int,
    n_folds: int = 5,
    seed: int = 0,
    floor: float = 1e-9,
) -> Selection:
    """Gap rule on held-out NPOE.

    ``fit_candidates(train_mask)`` fits on the training samples and returns
    ``projection(test_mask, k)`` giving Ñ (n_test, q, q) of the k-constraint model.
    The held-out NPOE of "all directions constrained" (Ñ = 0) closes the sequence.
    """
    from ccl_cli.linalg import total_variance

    scores = np.zeros(max_k + 1)
    for test in demo_folds(demo, n_folds, seed):
        projection = fit_candidates(~test)
        Ut = U[test]
        var = total_variance(Ut) if test.sum() > 1 else 1.0
        for k in range(1, max_k + 1):
            Nt = projection(test, k)
            res = Ut - np.einsum("nij,nj->ni", Nt, Ut)
            scores[k - 1] += np.mean(np.sum(res**2, 1)) / var
        scores[max_k] += np.mean(np.sum(Ut**2, 1)) / var
    sel = gap(scores / n_folds, floor, rule="cv")
    sel.reason = "held-out NPOE: " + sel.reason
    return sel
