"""A constant constraint that holds in some stretches of a recording only ("in stretches",
ALGORITHMS.md §3.1 on the stretches where it holds; issue 17).

A whole wiping recording — approach in free space, wipe on a table, retract — obeys A = nᵀ
while the tool is on the table and nothing elsewhere. Every global model sees the approach
and retract move along n far beyond the noise and answers k = 0. This model finds the
stretches where a common set of s rows is quiet and fits the rows on those stretches only.

Blocks: block b of demonstration d holds its samples with j·B ≤ t < (j + 1)·B (B = ``block``
s, j the block index), as the windows of :class:`~.windows.PerWindow`. With C_b the mean
second moment of the actions in block b (q, q), n_b its sample count and σ²(a) = aᵀΣa the
noise variance of aᵀu (Σ from :mod:`.noise_rank`'s robust estimates — second differences,
through the derivative filter when the velocities were derived — :func:`noise_covariance`):

* block b *moves* when tr C_b > MARGIN · Σ_i σ²(e_i) (its motion is above the noise);
* rows R (s, q), orthonormal, are *quiet* in block b when for every row r_k

      r_kᵀ C_b r_k ≤ MARGIN · σ²(r_k)       (motion along r_k at the noise level), or
      r_kᵀ C_b r_k ≤ SHARE_BLOCK · m̄        (a negligible share of the recording's typical
                                               motion m̄ = the median of tr C_b over the moving
                                               blocks: a tool pressing a little into a
                                               compliant table moves along n far above a good
                                               sensor's noise, and far below the strokes);

* the rows are the s eigenvectors with the smallest eigenvalues of Σ_{b quiet} n_b C_b (§3.1
  on the quiet blocks); they start from the moving block (of at most MAX_STARTS, spread
  evenly) whose own s smallest eigenvectors are quiet in the largest share of the moving
  time, and the rows and the quiet blocks are then
  updated in turn (at most ITERATIONS times);
* a block that does not move takes the label of the nearest moving block before it in its
  demonstration (else after it): at rest every direction is quiet, which says nothing.

The constraint holds in the quiet blocks: Ã(x) = R there and no rows elsewhere, so
Ñ = I − RᵀR where it holds and Ñ = I elsewhere (rows of zeros in :meth:`constraint`).

``share_`` is the share of the moving time where the constraint holds. Whether it holds in a
*sizeable* share of the time is judged on held-out data by learn-a's ``auto``
(:func:`held_out`): the rows learnt on the training folds must be quiet in at least
MIN_SHARE of the held-out moving time. Free motion finds a few lucky stretches whose motion
happens to avoid a direction; it does not find them in half of the held-out time.

New recordings: the rows describe a surface, not where the recording touches it. A sample of a
demonstration seen in ``fit`` takes the label of its block; new data are classified by
:meth:`ConstraintInStretches.classify` — the same rows, the new data's blocks labelled by the
motion along them. That is the model's stated rule for a recording it has not seen
(:attr:`~ConstraintInStretches.new_data_rule`, :meth:`~ConstraintInStretches.applies_to`;
``ccl evaluate`` / ``ccl predict`` apply a model so, and say so).

Shapes: X (N, p), U (N, q), groups (N,) demonstration ids, t (N,) s; ``A_`` (s, q);
``blocks_`` (B, 3) [demonstration id, block index j, holds (0/1)].
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn import model_selection as ms
from ccl_cli.learn.basis import cluster_moments
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.learn.constraint.base import (
    ONE_ACTION,
    Applied,
    NewDataRule,
    TimedConstraint,
    check_rows_asked,
    one_action_selection,
    unseen,
)
from ccl_cli.learn.constraint.timeblocks import nearest_window, window_index
from ccl_cli.learn.linalg import nullspace_projection
from ccl_cli.learn.params import Interval, MaxConstraints, Seconds, out_of_range, parameters

#: Block length (s) over which a stretch is judged.
BLOCK_S = 0.5
#: A row along which a block moves at most this share of the recording's typical motion is
#: quiet in it however far above the noise (a contact that gives a little: rms speed along it
#: at most 3 % of the typical rms speed; chosen on the simulations: docs/auto.md).
SHARE_BLOCK = 1e-3
#: Smallest share of the held-out moving time in which the rows must be quiet for the
#: constraint to be claimed (chosen on the simulations: docs/auto.md).
MIN_SHARE = 0.5
#: Updates of the rows and the quiet blocks.
ITERATIONS = 5
#: At most this many moving blocks (evenly spread over the recording) offer their own rows as
#: the start: the (starts × blocks) energies stay small on hour-long recordings.
MAX_STARTS = 256
MARGIN = nr.MARGIN


@dataclass
class Blocks:
    """Per block: mean second moment ``C`` (B, q, q), sample count ``n`` (B,), ``moving`` (B,),
    ``demo`` (B,); ``seg`` (N,) each sample's block; ``table`` (B, 2) [demo, j]; ``typical``
    m̄, the median of tr C_b over the moving blocks; ``noise`` Σ (q, q) the actions' noise
    covariance (:func:`noise_covariance`)."""

    C: np.ndarray
    n: np.ndarray
    moving: np.ndarray
    demo: np.ndarray
    seg: np.ndarray
    table: np.ndarray
    typical: float
    noise: np.ndarray


def blocks_of(data: nr.Sample, block: float) -> Blocks:
    """The blocks of ``data`` (module docstring), which moving."""
    U = data.U
    seg, table = window_index(data.groups, data.t, block, len(U))
    n_blocks = len(table)
    n = np.bincount(seg, minlength=n_blocks)
    C = cluster_moments(U, seg, n_blocks) / np.maximum(n, 1)[:, None, None]
    noise = noise_covariance(data)
    total = np.trace(C, axis1=1, axis2=2)
    moving = total > MARGIN * np.trace(noise)
    typical = float(np.median(total[moving])) if moving.any() else 0.0
    return Blocks(C, n, moving, table[:, 0], seg, table, typical, noise)


def noise_covariance(data: nr.Sample) -> np.ndarray:
    """Σ (q, q), the noise covariance of the actions, from the robust noise variances
    (:mod:`.noise_rank`) along the axes e_i and their diagonals (e_i + e_j)/√2: for Gaussian
    noise σ²(a) = aᵀΣa, so Σ_ij = σ²((e_i + e_j)/√2) − (Σ_ii + Σ_jj)/2 — q(q + 1)/2 robust
    estimates in place of one per candidate row."""
    q = data.U.shape[1]
    i, j = np.triu_indices(q, 1)
    diag = np.zeros((len(i), q))
    diag[np.arange(len(i)), i] = diag[np.arange(len(i)), j] = np.sqrt(0.5)
    var = data.rows_evidence(np.r_[np.eye(q), diag]).noise
    S = np.diag(var[:q])
    S[i, j] = S[j, i] = var[q:] - (var[i] + var[j]) / 2
    return S


def quiet(blocks: Blocks, rows: np.ndarray) -> np.ndarray:
    """Whether unit rows (s, q) — or candidate row sets (c, s, q) — are quiet in each block:
    (B,) or (c, B) (module docstring; σ²(r) = rᵀΣr)."""
    R = rows[None] if rows.ndim == 2 else rows
    sig = np.einsum("ckq,qr,ckr->ck", R, blocks.noise, R)
    energy = np.einsum("ckq,bqr,ckr->cbk", R, blocks.C, R)
    ok = (energy <= MARGIN * sig[:, None, :]) | (energy <= SHARE_BLOCK * blocks.typical)
    out = ok.all(-1)
    return out[0] if rows.ndim == 2 else out


def fill_still(holds: np.ndarray, moving: np.ndarray, demo: np.ndarray) -> np.ndarray:
    """Labels (B,) of blocks in demonstration and time order: a block that does not move takes
    the label of the nearest moving block before it in its demonstration, else after it
    (False when its demonstration has none)."""
    B = len(holds)
    idx = np.arange(B)
    prev = np.maximum.accumulate(np.where(moving, idx, -1))
    nxt = np.minimum.accumulate(np.where(moving, idx, B)[::-1])[::-1]
    ok_prev = (prev >= 0) & (demo[np.clip(prev, 0, B - 1)] == demo)
    ok_next = (nxt < B) & (demo[np.clip(nxt, 0, B - 1)] == demo)
    src = np.where(ok_prev, prev, np.where(ok_next, nxt, -1))
    return np.where(moving, holds, np.where(src >= 0, holds[np.clip(src, 0, B - 1)], False))


def common_rows(blocks: Blocks, s: int) -> tuple[np.ndarray, np.ndarray] | None:
    """Rows R (s, q) quiet in the largest share of the moving time and the moving blocks where
    they are quiet (B,) (module docstring); None when no block moves."""
    idx = np.flatnonzero(blocks.moving)
    if not len(idx):
        return None
    C, w = blocks.C, blocks.n * blocks.moving
    starts = idx[np.unique(np.linspace(0, len(idx) - 1, min(len(idx), MAX_STARTS)).astype(int))]
    own = np.transpose(np.linalg.eigh(C[starts])[1][:, :, :s], (0, 2, 1))  # (M, s, q) their own rows
    share = quiet(blocks, own) @ w
    rows = own[int(np.argmax(share))]
    holds = quiet(blocks, rows) & blocks.moving
    for _ in range(ITERATIONS):
        pooled = np.einsum("b,bqr->qr", w * holds, C)
        rows = np.linalg.eigh(pooled)[1][:, :s].T
        again = quiet(blocks, rows) & blocks.moving
        if np.array_equal(again, holds):
            break
        holds = again
    return rows, holds


@parameters
class ConstraintInStretches(TimedConstraint):
    """s constant rows that hold in the stretches of the recording where the motion along them
    is quiet, no constraint elsewhere (module docstring).

    Args:
        block: block length (s) over which a stretch is judged.
        n_constraints: rows s ≥ 1 (None: the most rows quiet in at least MIN_SHARE of the
            moving time, at least 1).

    Attributes:
        A_ (s, q) the rows, blocks_ (B, 3) [demonstration id, block index, holds], share_ the
        share of the moving time where the rows hold, stretches_ (list of [demonstration, start
        s, end s] where they hold), n_constraints_, n_action_, selection_, n_features_in_,
        heldout_ (set by learn-a's ``auto``: {error, mean, se, per_fold, folds}, else None).
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value",
        "share_": "value", "stretches_": "value", "heldout_": "value", "A_": "array", "blocks_": "array"}
    block: Seconds = BLOCK_S
    n_constraints: MaxConstraints = None

    local_to = "stretch"
    #: Its Ñ switches between I − RᵀR and I from stretch to stretch, not one matrix per window:
    #: it is normalised as the models whose Ã changes from sample to sample (§6, original).
    varies_with_state = True

    def fit(self, X: np.ndarray | None, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None) -> ConstraintInStretches:
        """Learn the rows and where they hold from U (N, q) of demonstrations ``groups`` at times
        ``t`` (N,) s; ``derivative`` says how U was made (as for ``auto``: the readers'
        {"window", "order"}, False when recorded, None when not known). Without ``t`` the blocks
        (in seconds) cannot be placed: InputError naming t. One action dimension (q = 1): no
        rows (k = 0, :data:`~.base.ONE_ACTION`), holding nowhere; ``t`` not read."""
        X, U = self._prepare_fit(X, U)
        q = U.shape[1]
        if q == 1:
            check_rows_asked(1, self.n_constraints)
            return self._one_action(groups, len(U))
        if self.n_constraints is not None and self.n_constraints > q - 1:
            raise ConfigError(out_of_range("n_constraints", self.n_constraints, Interval(1, q - 1, type=int)))
        if t is None:
            raise InputError("a constraint in stretches needs the sample times t")
        data = nr.Sample.of(X, U, groups, np.asarray(t, float), derivative)
        blocks = blocks_of(data, self.block)
        sizes = [self.n_constraints] if self.n_constraints is not None else range(1, q)
        found = None
        for s in sizes:  # the most rows that hold in a sizeable share (at least one)
            got = common_rows(blocks, s)
            if got is None:
                raise InputError("no block of the recording moves above the noise: no stretch to judge")
            share = _share(got[1], blocks)
            if found is not None and share < MIN_SHARE:
                break
            found = got
        rows, holds = found
        self.A_ = rows
        self.n_action_ = q
        self.n_constraints_ = int(rows.shape[0])
        self._label(blocks, holds)
        self.selection_ = {"rule": "stretches", "n_constraints": self.n_constraints_, "values": [],
                           "criterion": "share of the moving time where the rows are quiet",
                           "reason": self.summary()}
        self.heldout_ = None
        return self

    def _one_action(self, groups: np.ndarray | None, n: int) -> ConstraintInStretches:
        """k = 0 at one action dimension (:data:`~.base.ONE_ACTION`): no rows, holding nowhere; one
        block per demonstration (the times are not read)."""
        demos = window_index(groups, None, None, n)[1][:, 0]
        self.blocks_ = np.c_[demos, np.zeros((len(demos), 2), np.int64)]
        self.A_ = np.zeros((0, 1))
        self.n_action_, self.n_constraints_, self.share_, self.stretches_, self.heldout_ = 1, 0, 0.0, [], None
        self.selection_ = one_action_selection()
        return self

    def _label(self, blocks: Blocks, holds: np.ndarray) -> None:
        labels = fill_still(holds, blocks.moving, blocks.demo)
        self.blocks_ = np.c_[blocks.table, labels.astype(np.int64)]
        self.share_ = _share(holds, blocks)
        self.stretches_ = stretches(self.blocks_, self.block)

    def classify(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                 t: np.ndarray | None = None, derivative: HowMade = None
                 ) -> ConstraintInStretches:
        """The same rows on new data X (N, p), U (N, q) at times t (N,): a copy whose stretches
        are those of these data where the motion along the rows is quiet."""
        self._check_fitted("A_")
        X, U = self._check_states(X), np.asarray(U, dtype=float)
        if self.n_constraints_ == 0:  # one action dimension: no rows, nothing to classify
            out = ConstraintInStretches(block=self.block)._one_action(groups, len(X))
            out.n_features_in_ = self.n_features_in_
            return out
        if t is None:
            raise InputError("a constraint in stretches needs the sample times t")
        blocks, holds = label_blocks(nr.Sample.of(X, U, groups, np.asarray(t, float), derivative),
                                     self.A_, self.block)
        out = ConstraintInStretches(block=self.block, n_constraints=self.n_constraints)
        out.A_, out.n_action_, out.n_constraints_ = self.A_, self.n_action_, self.n_constraints_
        out.n_features_in_ = self.n_features_in_
        out._label(blocks, holds)
        out.selection_ = {**self.selection_, "reason": out.summary() + " (rows learnt before; stretches "
                          "classified on these data)"}
        out.heldout_ = None
        return out

    @property
    def new_data_rule(self) -> NewDataRule:
        """Stretches classified: the rows kept, where they hold found on the new data."""
        self._check_fitted("A_")
        return NewDataRule(
            "stretches classified", ("rows", "k", "block"),
            f"its {self.n_constraints_} row(s) describe a surface, not where a recording touches it: on "
            f"a recording it has not seen the rows are kept and they hold in the {self.block:g}-s blocks "
            "where the motion along them is quiet (labelled on those data)")

    def applies_to(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None, new_recording: bool = True) -> Applied:
        """Itself when every demonstration of ``groups`` (N,) was fitted here (and the data are
        a part of those recordings), else :meth:`classify` on X (N, p), U (N, q) at times t (N,)
        (:attr:`new_data_rule`), with the note saying so."""
        rule = self.new_data_rule
        if not unseen({int(d) for d in np.unique(self.blocks_[:, 0])}, groups, new_recording):
            return Applied(self, rule)
        refit = self.classify(X, U, groups=groups, t=t)
        return Applied(refit, rule, (
            f"a constraint that holds in stretches: its {self.n_constraints_} learnt row(s) on these data, "
            "holding where the motion along them is quiet — " + refit.summary()))

    def constant_rows(self) -> np.ndarray:
        """The rows (s, q) where the constraint holds."""
        self._check_fitted("A_")
        return self.A_

    def check_shapes(self) -> None:
        """blocks_ (B, 3) integers with a 0/1 label, A_ (s, q) with s ≥ 1 (none at q = 1)."""
        blocks = self.blocks_
        if blocks is None or blocks.ndim != 2 or blocks.shape[1] != 3 or \
                not np.array_equal(blocks, np.round(blocks)) or not np.isin(blocks[:, 2], (0, 1)).all():
            raise self._shape_error("blocks_")
        s, q = self.n_constraints_, self.n_action_
        if self.A_ is None or s < (1 if q > 1 else 0) or self.A_.shape != (s, q):
            raise self._shape_error("A_")
        super().check_shapes()

    def holds(self, X: np.ndarray, *, groups: np.ndarray | None = None, t: np.ndarray | None = None
              ) -> np.ndarray:
        """Whether the constraint holds at each sample (N,): the label of its block, else of the
        nearest fitted block of its demonstration."""
        self._check_fitted("A_")
        n = len(self._check_states(X))
        per = None if self.n_constraints_ == 0 else self.block  # no rows: one block per demonstration
        at = nearest_window(self.blocks_[:, :2], per, n, groups, t, "stretches")
        return self.blocks_[at, 2].astype(bool)

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã: the rows where the constraint holds, rows of zeros elsewhere (so Ñ = I − RᵀR
        there and I elsewhere): (N, s, q)."""
        on = self.holds(X, groups=groups, t=t)
        return np.where(on[:, None, None], self.A_[None], 0.0)

    def summary(self) -> str:
        """Where the constraint holds, in words."""
        if self.n_constraints_ == 0:
            return ONE_ACTION
        return describe(self.n_constraints_, self.share_, self.stretches_)


def _share(holds: np.ndarray, blocks: Blocks) -> float:
    """Share of the moving samples in blocks where the rows hold."""
    moving = blocks.n * blocks.moving
    return float((moving * holds).sum() / max(moving.sum(), 1))


def stretches(blocks: np.ndarray, block: float) -> list[list[float]]:
    """[demonstration, start s, end s] of every run of consecutive blocks where the constraint
    holds, from ``blocks`` (B, 3) [demonstration, block index, holds]."""
    on = blocks[:, 2].astype(bool)
    demo, j = blocks[:, 0], blocks[:, 1]
    start = on & np.r_[True, ~on[:-1] | (demo[1:] != demo[:-1]) | (j[1:] != j[:-1] + 1)]
    end = on & np.r_[~on[1:] | (demo[1:] != demo[:-1]) | (j[1:] != j[:-1] + 1), True]
    return [[int(d), float(a * block), float((b + 1) * block)]
            for d, a, b in zip(demo[start], j[start], j[end], strict=True)]


def describe(k: int, share: float, runs: list[list[float]], most: int = 4) -> str:
    """"k = 1 in 76 % of the moving time: demo 0 1.5–9.5 s, ...; free motion elsewhere"."""
    parts = [f"demo {int(d)} {a:.1f}–{b:.1f} s" for d, a, b in runs[:most]]
    more = f", … ({len(runs) - most} more)" if len(runs) > most else ""
    return (f"k = {k} in {100 * share:.0f} % of the moving time: {', '.join(parts)}{more}; "
            "free motion elsewhere")


def label_blocks(data: nr.Sample, rows: np.ndarray, block: float) -> tuple[Blocks, np.ndarray]:
    """The blocks of ``data`` and whether the rows (s, q) are quiet in each moving one (B,)."""
    blocks = blocks_of(data, block)
    return blocks, quiet(blocks, rows) & blocks.moving


@dataclass
class HeldOut:
    """The held-out evidence of the model in stretches (:func:`held_out`) for its k rows (k = 0:
    none holds): per sample its rows (N, k, q) — zeros where the held-out blocks do not hold —
    the share of the held-out moving time where they hold, the noise evidence on the held-out
    samples it claims, NPOE per fold, and the reason in words."""

    k: int
    rows: np.ndarray
    share: float
    evidence: nr.RowEvidence | None
    errors: np.ndarray
    reason: str


def held_out(data: nr.Sample, folds: ms.Folds, m: int, block: float = BLOCK_S) -> HeldOut:
    """k = the most rows s ≤ m such that the model with s rows, fitted on every training fold,
    holds in at least MIN_SHARE of the held-out moving time — its held-out blocks classified
    by the motion along its rows — and the noise rule (:mod:`.noise_rank`) on the held-out
    samples it claims finds all s rows quiet. Per fold NPOE of the held-out samples with
    Ñ = I − RᵀR where the rows hold, I elsewhere."""
    X, U, g, t = data.X, data.U, data.groups, data.t
    n, q = U.shape
    piece = np.zeros(n, np.int64)
    for j, (_, test) in enumerate(folds.pairs):
        piece[test] = j
    piece = np.cumsum(np.r_[True, (piece[1:] != piece[:-1]) | (g[1:] != g[:-1])])
    found = HeldOut(0, np.zeros((n, 0, q)), 0.0, None, np.zeros(len(folds.pairs)), "")
    for s in range(1, m + 1):
        rows, holds, moving = np.zeros((n, s, q)), np.zeros(n, bool), np.zeros(n, bool)
        errors = []
        for train, test in folds.pairs:
            model = ConstraintInStretches(block=block, n_constraints=s).fit(
                X[train], U[train], groups=g[train], t=t[train], derivative=data.derivative)
            sub = nr.Sample(X[test], U[test], piece[test], t[test], data.derived, data.recorded)
            blocks, on = label_blocks(sub, model.A_, block)
            holds[test] = fill_still(on, blocks.moving, blocks.demo)[blocks.seg]
            moving[test] = blocks.moving[blocks.seg]
            rows[test] = np.where(holds[test, None, None], model.A_[None], 0.0)
            errors.append(npoe_error(nullspace_projection(rows[test]), U[test]))
        share = float((holds & moving).sum() / max(moving.sum(), 1))
        run = np.cumsum(np.r_[True, (piece[1:] != piece[:-1]) | (holds[1:] != holds[:-1])])
        claimed = nr.Sample(X[holds], U[holds], run[holds], t[holds], data.derived, data.recorded)
        evidence = claimed.rows_evidence(rows[holds]) if holds.sum() > 3 else None
        chosen = None if evidence is None else nr.noise_rank(evidence, s, share_rows=nr.SHARE_ROWS)
        k = 0 if chosen is None else chosen.n_constraints
        ok = share >= MIN_SHARE and k >= s
        why = (f"{s} row(s) learnt on the training folds hold in {100 * share:.0f} % of the held-out moving "
               f"time (at least {100 * MIN_SHARE:.0f} % needed)"
               + ("" if chosen is None else f"; on the held-out samples they claim: {chosen.reason}"))
        if not ok:
            if s == 1:
                found = HeldOut(0, rows, share, evidence, np.asarray(errors), "no constraint: " + why)
            break
        found = HeldOut(s, rows, share, evidence, np.asarray(errors), why)
    return found
