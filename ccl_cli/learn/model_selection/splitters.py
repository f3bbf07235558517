"""Splitters: which samples train and which test, and why.

By demonstration when there are at least :data:`MIN_DEMOS` of them (the reported test split: at
least :data:`TEST_MIN_DEMOS`); otherwise contiguous time blocks (blocked K-fold), with ``gap``
samples dropped from the training side of every train/test boundary so that the windows of
derived velocities (a Savitzky–Golay window of w samples makes u_n depend on x_{n±w/2}) never
reach across it. :func:`inner_folds` holds out blocks *inside* each stretch, for models fitted
per stretch; :func:`holdout_split` chooses the reported train/test split of a recording;
:func:`tuning_subset` the rows a large search runs on.

scikit-learn's ``GroupKFold`` splits by demonstration as :func:`make_folds` does, but has no
blocked folds with guard gaps, no blocks held out inside stretches and no reasons in words;
these are ours (docs/internals.md, "Model selection").
"""

from __future__ import annotations

import hashlib
from collections.abc import Callable
from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.dataset import Derivative, HowMade
from ccl_cli.errors import InputError
from ccl_cli.learn.defaults import DEFAULT_GAP, MIN_DEMOS, N_BLOCKS, N_FOLDS, TEST_MIN_DEMOS, TUNE_MAX_ROWS


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
    ids, of_sample = np.unique(groups, return_inverse=True)
    if len(ids) >= max(min_demos, 2):
        k = min(n_folds, len(ids))
        perm = np.random.default_rng(seed).permutation(ids)
        fold_of = np.empty(len(ids), np.int64)  # each demonstration's fold: one pass over the samples
        for j, part in enumerate(np.array_split(np.searchsorted(ids, perm), k)):
            fold_of[part] = j
        fold = fold_of[of_sample.ravel()]
        pairs = [(np.flatnonzero(fold != j), np.flatnonzero(fold == j)) for j in range(k)]
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


def inner_heldout(segments: np.ndarray, derivative: HowMade,
                  error_of: Callable[[np.ndarray, np.ndarray], float], what: str = "segment",
                  max_rows: int = TUNE_MAX_ROWS) -> dict[str, Any] | None:
    """The held-out NPOE of a model fitted per segment (a demonstration or a window), which can
    be tested only on its own segments: :data:`N_FOLDS` :func:`inner_folds` of ``segments`` (N,)
    with the guard gap of how U was made (``derivative``: its window when derived, else
    :data:`RECORDED_GAP`); ``error_of(train, test)`` fits on the rows ``train`` and returns the
    error on the rows ``test``. {error, mean, se, per_fold, folds}, or None when most segments
    are too short for the blocks and their gaps. Above ``max_rows`` samples the folds are those
    of a bounded, seeded sample of whole segments (or contiguous blocks of long ones, as segments:
    :func:`tuning_subset`), and ``subset`` says what was taken: the work does not grow with N."""
    how = Derivative.of(derivative)
    gap = int(how.window) if how.derived else RECORDED_GAP
    seg = np.asarray(segments)
    found = tuning_subset(seg, len(seg), 0, max_rows) if len(seg) > max_rows else None
    rows = None
    if found is not None:
        rows, taken, note = found
        seg = np.unique(taken, return_inverse=True)[1].ravel()
    counts = np.bincount(seg)
    if (counts[seg] >= N_FOLDS * (2 * gap + MIN_BLOCK)).mean() < 0.5:
        return None
    folds = inner_folds(seg, N_FOLDS, gap, what)
    pairs = folds.pairs if rows is None else [(rows[train], rows[test]) for train, test in folds.pairs]
    e = np.array([error_of(train, test) for train, test in pairs])  # a loop over the folds
    out = {"error": "NPOE", "mean": float(e.mean()), "se": float(e.std(ddof=1) / np.sqrt(len(e))),
           "per_fold": e.tolist(), "folds": folds.reason}
    if found is not None:
        out["subset"] = note.replace("searched on", "measured on")
    return out


# -- the reported train/test split ----------------------------------------------------------
@dataclass
class Holdout:
    train: np.ndarray  # bool (N,)
    test: np.ndarray  # bool (N,)
    info: dict[str, Any] = field(default_factory=dict)


def shape_keys(X: np.ndarray, demo: np.ndarray) -> np.ndarray:
    """A key per demonstration (in the order of ``np.unique(demo)``) that depends on its samples
    only through what no change of frame, length unit, rate or file order changes: its number of
    samples and the shares of its positions' spread along their principal axes (the singular
    values of its centred states X (N, p), each over their sum, to 6 digits): (n_demos,) strings.
    Demonstrations ranked by these keys are held out alike whatever order they came in."""
    ids, inverse = np.unique(demo, return_inverse=True)
    order = np.argsort(inverse.ravel(), kind="stable")
    starts = np.searchsorted(inverse.ravel()[order], np.arange(len(ids)))
    keys = []
    for rows in np.split(order, starts[1:]):
        P = np.asarray(X[rows], dtype=float)
        sv = np.linalg.svd(P - P.mean(axis=0), compute_uv=False) if len(P) > 1 else np.zeros(1)
        share = sv / sv.sum() if np.isfinite(sv).all() and sv.sum() > 0 else np.zeros_like(sv)
        keys.append(f"{len(rows)}:" + ",".join(f"{v:.6f}" for v in share))
    return np.array(keys)


def _ranked(ids: np.ndarray, keys: np.ndarray | None, seed: int) -> np.ndarray:
    """``ids`` in a seeded order: of their ``keys`` when given (the same whatever the order of
    the ids), else of their position."""
    if keys is None:
        return np.random.default_rng(seed).permutation(ids)
    digest = [hashlib.blake2b(f"{seed}|{k}".encode(), digest_size=8).hexdigest() for k in keys]
    return ids[np.lexsort((keys, digest))]


def holdout_split(demo: np.ndarray, fraction: float = 0.3, seed: int = 0, gap: int = DEFAULT_GAP,
                  min_demos: int = TEST_MIN_DEMOS, n_blocks: int = N_BLOCKS, keys: np.ndarray | None = None
                  ) -> Holdout:
    """The reported train/test split: by demonstration when there are at least
    ``min_demos``; else ``n_blocks`` contiguous time blocks of which round(fraction ·
    n_blocks) (seeded) are held out, with ``gap`` samples dropped from training at each
    boundary. ``keys`` (one per demonstration, :func:`shape_keys`) rank the demonstrations:
    those held out whole, and the order in which the time blocks of fewer are laid over them
    (each in time order), so that which samples are held out does not depend on the order the
    demonstrations came in. ``info``: kind, reason, n_train/n_test demos or blocks, samples, gap."""
    if not 0.0 < fraction < 1.0:
        raise InputError(f"test fraction must be in (0, 1), got {fraction}")
    demo = np.asarray(demo)
    n = len(demo)
    ids = np.unique(demo)
    rng = np.random.default_rng(seed)
    possible = min(n_blocks, n // (2 * gap + 4))  # blocks long enough for their guard gaps
    if len(ids) >= max(min_demos, 2) or (possible < 3 and len(ids) >= 2):
        n_test = min(max(1, int(round(fraction * len(ids)))), len(ids) - 1)
        test_ids = (rng.choice(ids, size=n_test, replace=False) if keys is None
                    else _ranked(ids, keys, seed)[:n_test])
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
    # the blocks are laid over the demonstrations in their ranked order (each in time order)
    laid = np.arange(n)
    if keys is not None and len(ids) > 1:
        rank = np.empty(len(ids), np.int64)
        rank[np.searchsorted(ids, _ranked(ids, keys, seed))] = np.arange(len(ids))
        laid = np.lexsort((laid, rank[np.searchsorted(ids, demo)]))
    test_pos = np.concatenate([blocks[i] for i in chosen])
    train = np.zeros(n, bool)
    train[laid[_guarded_train(n, test_pos, gap)]] = True
    test = np.zeros(n, bool)
    test[laid[test_pos]] = True
    why = ("a single continuous recording" if len(ids) == 1 else f"only {len(ids)} demonstrations")
    info = {"kind": "blocks",
            "reason": f"{why} (< {min_demos}): {n_test} of {len(blocks)} contiguous time blocks held out, "
                      f"{gap} samples dropped from training at each boundary",
            "n_train_blocks": int(len(blocks) - n_test), "n_test_blocks": int(n_test),
            "test_blocks": [int(i) for i in chosen], "gap": int(gap),
            "n_train_samples": int(train.sum()), "n_test_samples": int(test.sum()),
            "n_dropped_samples": int(n - train.sum() - test.sum()), "fraction": fraction}
    return Holdout(train, test, info)


def tuning_subset(groups: np.ndarray | None, n: int, seed: int = 0,
                  max_rows: int | None = None) -> tuple[np.ndarray, np.ndarray, str] | None:
    """Rows on which to search hyperparameters when there are more than ``max_rows``
    (default :data:`TUNE_MAX_ROWS`): whole demonstrations in a seeded random order until
    about ``max_rows`` samples (at least :data:`MIN_DEMOS` of them) — or, when those
    MIN_DEMOS demonstrations alone hold more than ``max_rows`` samples, one contiguous block of
    ``max_rows`` / MIN_DEMOS samples from each, at a seeded place — or, with fewer
    demonstrations than MIN_DEMOS, :data:`N_BLOCKS` contiguous pieces spread over each
    recording, which then act as the groups of the search's folds. Never more than about
    ``max_rows`` rows, whatever the length of the demonstrations.

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
        if sizes[order[:MIN_DEMOS]].sum() <= max_rows:  # then take[:MIN_DEMOS] holds
            chosen = ids[order[take]]
            rows = np.flatnonzero(np.isin(g, chosen))
            if len(rows) < n:
                return rows, g[rows], (f"searched on {len(rows)} of {n} samples: {len(chosen)} of "
                                       f"{len(ids)} whole demonstrations (seed {seed})")
            return None
        chosen = np.sort(order[:MIN_DEMOS])  # long demonstrations: a block of each of MIN_DEMOS
        length = max_rows // MIN_DEMOS
        parts = []
        for i in chosen:  # a loop over MIN_DEMOS demonstrations
            mine = np.flatnonzero(g == ids[i])
            start = int(rng.integers(0, max(len(mine) - length, 0) + 1))
            parts.append(mine[start:start + length])
        rows = np.sort(np.concatenate(parts))
        return rows, g[rows], (f"searched on {len(rows)} of {n} samples: a contiguous block of at most "
                               f"{length} samples from each of {MIN_DEMOS} of {len(ids)} demonstrations "
                               f"(seed {seed})")
    piece = max_rows // N_BLOCKS
    starts = np.linspace(0, n - piece, N_BLOCKS).astype(int)
    rows = (starts[:, None] + np.arange(piece)[None, :]).ravel()
    return rows, np.repeat(np.arange(N_BLOCKS), piece), (
        f"searched on {len(rows)} of {n} samples: {N_BLOCKS} contiguous pieces of {piece} "
        "spread over the recording, each a group of the folds")
