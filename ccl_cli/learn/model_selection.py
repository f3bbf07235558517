"""Honest validation: splitters, one cross-validation function, hyperparameter tuning.

* Splitters. By demonstration when there are at least :data:`MIN_DEMOS` of them;
  otherwise contiguous time blocks (blocked K-fold), with ``gap`` samples dropped from
  the training side of every train/test boundary so that the windows of derived
  velocities (a Savitzky–Golay window of w samples makes u_n depend on x_{n±w/2}) never
  reach across it.
* :func:`cross_validate` fits a clone of any learner on each training fold and scores
  its own held-out consistency error on the test fold — never ground truth:

  - constraint models: NPOE (§6) of the held-out actions, ``mean ‖u − Ñ(x)u‖² / Σ var(u)``
    (per truncation k = 1..s when asked, for choosing the number of constraints);
  - null-space component (ncl): NPE (§6), ``mean ‖P̃u − w̃‖² / Σ var(u)``;
  - policies: the normalised inconsistency error (§5) ``mean ‖u − ûûᵀ π̃(x)‖² / Σ var(u)``
    (pi-weighted: each term weighted by ‖u‖², its own criterion; pi-coupled:
    ``mean ‖u − Ñ π̃(x)‖² / Σ var(u)`` with the given projections).

* :func:`holdout_split` chooses the reported train/test split of a recording and says
  why; :func:`tune` searches a small grid of hyperparameters within a time budget.
"""

from __future__ import annotations

import itertools
import time
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.learn.base import clone
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


# -- scores ---------------------------------------------------------------------------------
def _var(U: np.ndarray) -> float:
    v = float(np.var(U, axis=0, ddof=1).sum()) if len(U) > 1 else 0.0
    return v if v > 0 else float(np.mean(np.sum(U**2, 1))) or 1.0


def npoe_score(N: np.ndarray, U: np.ndarray) -> float:
    """NPOE = mean ‖u − Ñu‖² / Σ var(u): N (n, q, q), U (n, q)."""
    res = U - np.einsum("nij,nj->ni", N, U)
    return float(np.mean(np.sum(res**2, 1)) / _var(U))


def npe_score(W: np.ndarray, U: np.ndarray) -> float:
    """NPE = mean ‖P̃u − w̃‖² / Σ var(u), P̃ = w̃w̃ᵀ/‖w̃‖²: W, U (n, q)."""
    c = np.maximum(np.sum(W**2, 1), 1e-300)
    proj = W * (np.sum(W * U, 1) / c)[:, None]
    return float(np.mean(np.sum((proj - W) ** 2, 1)) / _var(U))


def inconsistency_score(P: np.ndarray, U: np.ndarray, N: np.ndarray | None = None,
                        weighted: bool = False) -> float:
    """mean ‖u − ûûᵀπ̃‖² / Σ var(u) (§5), or with projections N (n, q, q) mean ‖u − Ñπ̃‖²;
    ``weighted`` (pi-weighted's own criterion): each sample's term weighted by ‖u‖² / mean ‖u‖²."""
    if N is not None:
        res = U - np.einsum("nij,nj->ni", N, P)
        w = np.ones(len(U))
    else:
        norm = np.linalg.norm(U, axis=1)
        keep = norm > 0
        uh = U[keep] / norm[keep, None]
        res = U[keep] - uh * np.sum(uh * P[keep], 1)[:, None]
        w = norm[keep] ** 2 if weighted else np.ones(int(keep.sum()))
    return float(np.sum(w * np.sum(res**2, 1)) / max(np.sum(w), 1e-300) / _var(U))


def score(model: Any, X: np.ndarray, U: np.ndarray, demo: np.ndarray | None = None,
          projections: np.ndarray | None = None) -> float:
    """The learner's own held-out consistency error (see the module docstring)."""
    if hasattr(model, "projection"):
        return npoe_score(model.projection(X, demo), U)
    if hasattr(model, "task_component"):  # null-space component (ncl)
        return npe_score(model.predict(X), U)
    method = getattr(model, "method", None)
    if method == "pi-coupled":
        return inconsistency_score(model.predict(X), U, projections)
    return inconsistency_score(model.predict(X), U, weighted=method == "pi-weighted")


def truncated_npoe(model: Any, X: np.ndarray, U: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray:
    """Held-out NPOE of the model's first k rows, k = 1..n_constraints_ (nested learners)."""
    return np.array([npoe_score(model.projection_k(X, k), U) for k in range(1, model.n_constraints_ + 1)])


# -- cross-validation -----------------------------------------------------------------------
@dataclass
class CVResult:
    scores: np.ndarray  # (n_folds,) or (n_folds, m)
    kind: str
    reason: str

    @property
    def mean(self) -> np.ndarray | float:
        return self.scores.mean(0)

    @property
    def se(self) -> np.ndarray | float:
        k = self.scores.shape[0]
        return self.scores.std(0, ddof=1) / np.sqrt(k) if k > 1 else np.zeros_like(self.mean)


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
    """Fit a clone of ``estimator`` on each training fold, score it on the test fold.

    Args:
        estimator: any learner of this package (unfitted; it is cloned per fold).
        X (N, p), U (N, q): states and actions; groups (N,): demonstration ids.
        folds: explicit folds; by default :func:`make_folds` (by demonstration when
            there are enough, else contiguous blocks with ``gap``-sample guards).
        scorer: ``scorer(model, X_test, U_test, demo_test)`` → float or (m,) array;
            default :func:`score`.
        projections: (N, q, q) Ñ per sample for ``pi-coupled`` (subset per fold).

    Returns:
        :class:`CVResult` with ``scores`` (n_folds,) or (n_folds, m).
    """
    X = np.asarray(X, dtype=float)
    U = np.asarray(U, dtype=float)
    n = len(U)
    groups = np.zeros(n, int) if groups is None else np.asarray(groups)
    folds = folds or make_folds(groups, n, n_folds, seed, gap)
    out = []
    for train, test in folds.pairs:
        model = clone(estimator)
        kw = {}
        if projections is not None:
            kw["projections"] = projections[train]
        if _takes_demo(model):
            kw["demo"] = groups[train]
        model.fit(X[train], U[train], **kw)
        if scorer is not None:
            out.append(scorer(model, X[test], U[test], groups[test]))
        else:
            out.append(score(model, X[test], U[test], groups[test],
                             None if projections is None else projections[test]))
    return CVResult(np.asarray(out, dtype=float), folds.kind, folds.reason)


def _takes_demo(model: Any) -> bool:
    import inspect

    return "demo" in inspect.signature(model.fit).parameters


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


def tune(
    estimator: Any,
    X: np.ndarray,
    U: np.ndarray,
    groups: np.ndarray | None,
    grid: dict[str, list[Any]],
    *,
    budget: float = 10.0,
    n_folds: int = N_FOLDS,
    seed: int = 0,
    gap: int = DEFAULT_GAP,
    projections: np.ndarray | None = None,
) -> tuple[dict[str, Any], dict[str, Any]]:
    """Grid search by :func:`cross_validate` within ``budget`` seconds.

    Candidates are tried in the grid's order (the default and the cheap first); a
    candidate is skipped (and counted in ``skipped``) when the time spent plus what the
    previous candidate took would exceed ``budget``; the first two always run (so a
    two-candidate grid gives the same answer on a slow or busy machine). The
    candidate with the smallest mean held-out error wins.

    Returns:
        (chosen parameters, info) with info = {"grid", "scores": [{params, mean, se}],
        "chosen", "budget", "budget_used", "skipped", "folds"}.
    """
    if not grid:
        raise ConfigError("tuning needs a non-empty grid")
    keys = list(grid)
    combos = [dict(zip(keys, vals, strict=True)) for vals in itertools.product(*(grid[k] for k in keys))]
    n = len(U)
    groups = np.zeros(n, int) if groups is None else np.asarray(groups)
    folds = make_folds(groups, n, n_folds, seed, gap)
    t0 = time.perf_counter()
    rows: list[dict[str, Any]] = []
    skipped = 0
    last, last_size = 0.0, 1
    for params in combos:
        size = _size(params)
        if len(rows) >= 2 and time.perf_counter() - t0 + last * max(1.0, size / last_size) ** 2 > budget:
            skipped += 1
            continue
        est = clone(estimator).set_params(**params)
        t1 = time.perf_counter()
        try:
            res = cross_validate(est, X, U, groups, folds=folds, projections=projections)
        except (InputError, LearningError, np.linalg.LinAlgError):
            continue  # e.g. more centres than training samples in a fold
        finally:
            last, last_size = time.perf_counter() - t1, size
        mean = float(res.mean)
        rows.append({"params": params, "mean": mean if np.isfinite(mean) else float("inf"),
                     "se": float(res.se)})
    if not rows:
        raise InputError("no hyperparameter candidate could be cross-validated on this data")
    best = min(range(len(rows)), key=lambda i: rows[i]["mean"])
    chosen = rows[best]["params"]
    info = {"grid": {k: list(v) for k, v in grid.items()}, "scores": rows, "chosen": chosen,
            "budget": budget, "budget_used": round(time.perf_counter() - t0, 3), "skipped": skipped,
            "folds": {"kind": folds.kind, "n": len(folds.pairs), "reason": folds.reason},
            "rule": "smallest held-out error"}
    return chosen, info


def _size(params: dict[str, Any]) -> int:
    """Number of basis functions of a candidate (its cost grows with it)."""
    basis = params.get("basis")
    return int(basis.get("n_centres", 1)) if isinstance(basis, dict) else int(params.get("n_centres", 1))


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
