"""A constraint that holds in the contact stretches a force channel shows, one row per stretch, none
elsewhere (:mod:`.contact`; ALGORITHMS.md §3.1 on each stretch).

``fit(X, U, groups=, t=, force=)`` finds the stretches where the tool is in contact — the force on,
pushing along a direction the motion does not take — and each stretch's row: the velocities'
smallest direction over it, cross-checked with the force. Ã = nᵀ in a stretch (Ñ = I − nnᵀ) and no
rows elsewhere (Ñ = I): approach and retract are free.

A sample of a demonstration seen in ``fit`` holds when its time lies within one of that
demonstration's stretches. A recording it has not seen carries no contact labels (and often no force
when it is applied): its blocks of ``block`` s are *classified* by their motion — a moving block holds
the learnt row along which its motion is quiet (the rule of :class:`~.stretches.ConstraintInStretches`,
the quietest of the learnt rows when several are), a block at rest takes the label of its moving
neighbour (:attr:`ContactPhases.new_data_rule`).

Shapes: X (N, p), U (N, q = 3), groups (N,), t (N,) s, force (N, 3); ``A_`` (S, 1, q) the rows of the
S stretches in ``spans_`` (S, 3) [demonstration id, first sample's time, last sample's time] (s).
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import InputError
from ccl_cli.learn.constraint import contact as ct
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.learn.constraint import stretches as st
from ccl_cli.learn.constraint.base import Applied, NewDataRule, TimedConstraint, Windows, unseen
from ccl_cli.learn.params import Seconds, parameters


@parameters
class ContactPhases(TimedConstraint):
    """One row per contact stretch of a force channel, none elsewhere (module docstring).

    Args:
        block: the block length (s) a recording it has not seen is classified on.

    Attributes:
        A_ (S, 1, q) a row per stretch, spans_ (S, 3) [demonstration id, start s, end s], demos_ the
        demonstrations it was fitted on,
        n_constraints_ (1 with a stretch, else 0), n_action_, share_ (the share of the samples in
        contact), contact_ (what the forces showed, JSON: :meth:`.contact.Contact.summary`),
        selection_, n_features_in_, heldout_ (None).
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value",
        "share_": "value", "contact_": "value", "heldout_": "value", "A_": "array", "spans_": "array",
        "demos_": "array"}
    block: Seconds = st.BLOCK_S

    local_to = "stretch"
    #: Ñ switches between I − nnᵀ and I from stretch to stretch: normalised as the models whose Ã
    #: changes from sample to sample (§6, original), as :class:`~.stretches.ConstraintInStretches`.
    varies_with_state = True

    def fit(self, X: np.ndarray | None, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None, force: np.ndarray | None = None
            ) -> ContactPhases:
        """Find the contact stretches and their rows from the force (N, 3) and the actions U (N, 3)
        of demonstrations ``groups`` at times ``t`` (N,) s (:func:`.contact.find`); ``derivative``
        is not read (the force says where the constraint holds, not the noise)."""
        X, U = self._prepare_fit(X, U)
        if force is None:
            raise InputError("contact phases need the force at each sample (force=..., data.force)")
        if t is None:
            raise InputError("contact phases need the sample times t")
        g = np.zeros(len(U), np.int64) if groups is None else np.asarray(groups)
        t = np.asarray(t, float)
        return self._take(ct.find(force, U, g, t), U.shape[1], g, t)

    def _take(self, found: ct.Contact, q: int, groups: np.ndarray, t: np.ndarray) -> ContactPhases:
        """The learnt attributes from what :func:`.contact.find` showed on q-D actions of
        demonstrations ``groups`` at times ``t`` (N,)."""
        self.A_ = np.array([s.row for s in found.stretches], dtype=float).reshape(-1, 1, q)
        self.spans_ = np.array([[s.demo, t[s.start], t[s.stop - 1]] for s in found.stretches],
                               dtype=float).reshape(-1, 3)
        self.demos_ = np.unique(groups).astype(np.int64)
        self.n_constraints_ = 1 if len(self.A_) else 0
        self.n_action_ = q
        self.share_ = float(found.mask.mean()) if len(found.mask) else 0.0
        self.contact_ = found.summary(t, groups)
        self.selection_ = {"rule": "contact", "n_constraints": self.n_constraints_, "values": [],
                           "criterion": "a reaction along the row and no motion along it (forces)",
                           "reason": self.summary()}
        self.heldout_ = None
        return self

    # -- what it predicts -------------------------------------------------------------------
    def stretch_of(self, n: int, groups: np.ndarray | None, t: np.ndarray | None) -> np.ndarray:
        """Index (n,) into ``spans_`` of the stretch holding each sample, −1 outside every one."""
        self._check_fitted("A_")
        out = np.full(n, -1, np.int64)
        if not len(self.spans_):
            return out
        if t is None:
            raise InputError("a contact-phase constraint model needs the sample times t")
        g = np.zeros(n, np.int64) if groups is None else np.asarray(groups).astype(np.int64)
        t = np.asarray(t, float)
        for j, (d, a, b) in enumerate(self.spans_):  # a loop over stretches, each batched over samples
            out[(g == int(d)) & (t >= a) & (t <= b)] = j
        return out

    def holds(self, X: np.ndarray, *, groups: np.ndarray | None = None, t: np.ndarray | None = None
              ) -> np.ndarray:
        """Whether a sample lies in a contact stretch (N,)."""
        return self.stretch_of(len(self._check_states(X)), groups, t) >= 0

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã: the row of the sample's stretch, a row of zeros outside contact: (N, 1, q)."""
        at = self.stretch_of(len(self._check_states(X)), groups, t)
        out = np.zeros((len(at), 1, self.n_action_))
        out[at >= 0] = self.A_[at[at >= 0]]
        return out

    def constant_rows(self) -> np.ndarray | None:
        """The row (1, q) when every stretch has the same one, else None."""
        self._check_fitted("A_")
        if not len(self.A_) or not np.allclose(np.abs(self.A_[:, 0] @ self.A_[0, 0]), 1.0, atol=1e-12):
            return None
        return self.A_[0]

    def windows(self) -> Windows | None:
        """The contact stretches in time and their rows."""
        self._check_fitted("A_")
        return Windows("contact stretch", self.spans_, self.A_) if len(self.A_) else None

    def summary(self) -> str:
        """Where the constraint holds, in words."""
        runs = [[d, a, b] for d, a, b in self.spans_]
        if not runs:
            return "no contact: the force never pushes along a direction the motion does not take"
        return st.describe(1, self.share_, runs).replace("of the moving time", "of the samples (contact)")

    # -- a recording it has not seen ---------------------------------------------------------
    @property
    def new_data_rule(self) -> NewDataRule:
        """Stretches classified by the motion along the learnt rows."""
        self._check_fitted("A_")
        return NewDataRule(
            "stretches classified", ("rows", "block"),
            f"its {len(self.A_)} contact row(s) describe the surfaces the tool touched, not where a new "
            f"recording touches them: a recording it has not seen holds, in each {self.block:g}-s block, the "
            "learnt row along which its motion is quiet (none: free)")

    def applies_to(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None, new_recording: bool = True) -> Applied:
        """Itself for a part of the recordings it was fitted on, else :meth:`classify`."""
        rule = self.new_data_rule
        if not unseen({int(d) for d in self.demos_}, groups, new_recording):
            return Applied(self, rule)
        out = self.classify(X, U, groups=groups, t=t)
        return Applied(out, rule, "contact rows learnt from the forces, classified on these data by the "
                                  "motion along them — " + out.summary())

    def classify(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                 t: np.ndarray | None = None) -> ContactPhases:
        """The learnt rows on new data X (N, p), U (N, q) at times t (N,): a copy whose stretches are
        the runs of blocks where the motion along one of the rows is quiet (the quietest)."""
        self._check_fitted("A_")
        X, U = self._check_states(X), np.asarray(U, dtype=float)
        if t is None:
            raise InputError("a contact-phase constraint model needs the sample times t")
        t = np.asarray(t, float)
        g = np.zeros(len(U), np.int64) if groups is None else np.asarray(groups).astype(np.int64)
        out = ContactPhases(block=self.block)
        out.n_features_in_ = self.n_features_in_
        rows, spans = np.zeros((0, 1, self.n_action_)), np.zeros((0, 3))
        if len(self.A_):
            blocks = st.blocks_of(nr.Sample.of(X, U, g, t, None), self.block)
            energy = np.einsum("sq,bqr,sr->sb", self.A_[:, 0], blocks.C, self.A_[:, 0])
            quiet = st.quiet(blocks, self.A_) & blocks.moving  # (S, B)
            best = np.where(quiet, energy, np.inf).argmin(0)
            label = np.where(quiet.any(0), best, -1)
            filled = _fill(label, blocks.moving, blocks.demo)
            rows, spans = _spans(filled, blocks, self.A_, self.block, t)
        out.A_, out.spans_ = rows, spans
        out.n_constraints_, out.n_action_ = (1 if len(rows) else 0), self.n_action_
        inside = out.stretch_of(len(U), g, t) >= 0
        out.share_ = float(inside.mean()) if len(U) else 0.0
        out.demos_ = np.unique(g).astype(np.int64)
        out.contact_ = None
        out.selection_ = {**self.selection_, "reason": out.summary() + " (rows learnt before; stretches "
                          "classified on these data)"}
        out.heldout_ = None
        return out

    def check_shapes(self) -> None:
        """spans_ (S, 3) with integer demonstration ids and end ≥ start, A_ (S, 1, q)."""
        spans = self.spans_
        if spans is None or spans.ndim != 2 or spans.shape[1] != 3 or not (spans[:, 2] >= spans[:, 1]).all() \
                or not np.array_equal(spans[:, 0], np.round(spans[:, 0])):
            raise self._shape_error("spans_")
        if self.A_ is None or self.A_.shape != (len(spans), 1, self.n_action_):
            raise self._shape_error("A_")
        super().check_shapes()


def _fill(label: np.ndarray, moving: np.ndarray, demo: np.ndarray) -> np.ndarray:
    """Block labels (B,) with each block at rest given the label of the nearest moving block before
    it in its demonstration, else after it (:func:`.stretches.fill_still` on each label)."""
    out = np.full(len(label), -1)
    for j in np.unique(label[label >= 0]):  # a loop over the learnt rows
        out[st.fill_still(label == j, moving, demo)] = j
    return out


def _spans(label: np.ndarray, blocks: st.Blocks, rows: np.ndarray, block: float, t: np.ndarray
           ) -> tuple[np.ndarray, np.ndarray]:
    """Runs of consecutive blocks with one label ≥ 0 → (rows (S, 1, q), spans (S, 3)) in seconds."""
    demo, j = blocks.table[:, 0], blocks.table[:, 1]
    cut = np.r_[True, (label[1:] != label[:-1]) | (demo[1:] != demo[:-1]) | (j[1:] != j[:-1] + 1)]
    start = np.flatnonzero(cut)
    stop = np.r_[start[1:], len(label)]
    keep = label[start] >= 0
    start, stop = start[keep], stop[keep]
    spans = np.column_stack([demo[start], j[start] * block, (j[stop - 1] + 1) * block - 1e-9 * block])
    return rows[label[start]], spans.astype(float)


def fitted_from(found: ct.Contact, X: np.ndarray, U: np.ndarray, groups: np.ndarray, t: np.ndarray
                ) -> ContactPhases:
    """A :class:`ContactPhases` holding what :func:`.contact.find` showed on X (N, p), U (N, q) (no
    second search)."""
    model = ContactPhases()
    model._prepare_fit(X, U)
    return model._take(found, U.shape[1], np.asarray(groups), np.asarray(t, float))
