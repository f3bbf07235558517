"""One constant constraint per time window of each demonstration ("per window", ALGORITHMS.md
§3.1 on each window; issue 17).

A constraint that changes over a recording (a board that tilts, a grip that changes) is nearly
constant over a short enough window. The windows are fixed in time, not by the data: window j of
demonstration d holds its samples with j·W ≤ t < (j + 1)·W (W = ``window`` s); ``window=None``
makes one window of each demonstration ("per demonstration"). A subset of the samples (a
training fold) therefore has the same windows as the whole recording.

In window w the s rows are the eigenvectors with the smallest eigenvalues (§3.1) of

    C_w = Σ_{n ∈ w} u_n u_nᵀ + ρ n_w C̄,        C̄ = (1/N) Σ_n u_n u_nᵀ (all windows),

n_w the window's sample count, ρ = ``shrinkage``. The prior term decides what a window alone
cannot: where the window's motion spans fewer than q − s directions (one straight stroke, a
pause) its noise eigenvalues tie, and C̄ picks among them the direction all the data move
least along; where the window's motion is clear, the term only adds ρ × the pooled
second moment, which moves a row little.

Prediction needs each sample's demonstration and time: a sample of a demonstration seen in
``fit`` takes the rows of its window, or of the nearest fitted window of that demonstration
(a held-out stretch that covers whole windows). A demonstration not seen in ``fit`` has no
constraint here. The model's rule for one (:meth:`PerWindow.applies_to`, stated in
:attr:`PerWindow.new_data_rule`): the same kind of model — window, shrinkage and k rows per
window fixed — is fitted on the new demonstration's own windows, and the application says so
(its errors there are training figures). ``ccl evaluate`` / ``ccl predict`` apply a model so.

Shapes: X (N, p), U (N, q), groups (N,) demonstration ids, t (N,) seconds; ``A_`` (S, s, q)
the rows of the S windows in ``windows_`` (S, 2): demonstration id, window index j.
"""

from __future__ import annotations

from typing import ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import InputError
from ccl_cli.learn.base import clone
from ccl_cli.learn.basis import cluster_moments
from ccl_cli.learn.consistency import npoe_error
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.learn.constraint import rank as sel
from ccl_cli.learn.constraint.base import (
    Applied,
    NewDataRule,
    TimedConstraint,
    Windows,
    check_rows_asked,
    one_action_selection,
    refit_note,
    unseen,
)
from ccl_cli.learn.constraint.timeblocks import nearest_window, window_ends, window_index
from ccl_cli.learn.defaults import WINDOW_S
from ccl_cli.learn.model_selection import inner_heldout
from ccl_cli.learn.params import NConstraints, NonNegative, Seconds, parameters

#: ρ of the prior term: the weight of the pooled second moment in each window's.
SHRINKAGE = 0.1


def window_moments(U: np.ndarray, seg: np.ndarray, n_seg: int) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The parts of C_w (module docstring) of every window: Σ_{n ∈ w} u_n u_nᵀ (n_seg, q, q),
    the sample counts n_w (n_seg,) and the pooled second moment C̄ (q, q); U (N, q), seg (N,)
    in 0..n_seg−1."""
    return cluster_moments(U, seg, n_seg), np.bincount(seg, minlength=n_seg), U.T @ U / max(len(U), 1)


def window_rows(U: np.ndarray, seg: np.ndarray, n_seg: int, shrinkage: float) -> np.ndarray:
    """Rows of every window in order of use (ascending eigenvalues of C_w, module docstring):
    U (N, q), seg (N,) in 0..n_seg−1 → (n_seg, q, q)."""
    S, counts, pooled = window_moments(U, seg, n_seg)
    _, vecs = np.linalg.eigh(S + shrinkage * counts[:, None, None] * pooled[None])
    return np.transpose(vecs, (0, 2, 1))


@parameters
class PerWindow(TimedConstraint):
    """A constant constraint (nhat) per window of ``window`` seconds of each demonstration.

    Args:
        window: window length in seconds (None: one window per demonstration).
        n_constraints: rows per window, the same in every window (0 … q − 1); None: chosen
            by the noise-aware rule (:mod:`~ccl_cli.learn.constraint.noise_rank`) on the
            rows of all windows, else — when the samples are not trajectories it can judge —
            by the ``ratio`` rule on the windows' mean eigenvalues.
        shrinkage: ρ, the weight of the pooled second moment in each window's (module docstring).
        heldout: also measure the held-out NPOE (``heldout_``): the same model fitted without
            blocks held out inside every window (:func:`~ccl_cli.learn.model_selection.inner_folds`,
            5 folds), scored on them — the held-out figure of a model that speaks only for the
            windows it was fitted on.

    Attributes:
        A_ (S, s, q) rows per window, windows_ (S, 2) [demonstration id, window index],
        n_constraints_, n_action_, selection_, n_features_in_, heldout_ ({error, mean, se,
        per_fold, folds}, or None when not measured or the windows are too short).
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "n_action_": "value", "selection_": "value",
        "window_": "value", "heldout_": "value", "A_": "array", "windows_": "array"}
    window: Seconds | None = WINDOW_S
    n_constraints: NConstraints = None
    shrinkage: NonNegative = SHRINKAGE
    heldout: bool = True

    def fit(self, X: np.ndarray | None, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None) -> PerWindow:
        """Learn the rows of every window from U (N, q) with demonstration ids ``groups`` and
        times ``t`` (N,) s. ``derivative`` says how U was made, for the noise of the rank rule
        (as :meth:`AutoConstraint.fit <ccl_cli.learn.constraint.auto.AutoConstraint.fit>`: the
        readers' {"window", "order"}, False when recorded, None when not known). X (N, p) is
        used for p and, for derived actions, as the positions. Without ``t`` the windows (in
        seconds) cannot be placed: InputError naming t (``window`` None needs no times). One
        action dimension (q = 1): no rows (k = 0, :data:`~.base.ONE_ACTION`), one piece per
        demonstration, ``t`` not read."""
        X, U = self._prepare_fit(X, U)
        n, q = U.shape
        check_rows_asked(q, self.n_constraints)
        if q == 1:
            return self._one_action(U, groups)
        if t is None and self.window is not None:
            raise InputError(f"one constraint per {self.per} needs the sample times t (fit(X, U, t=...))")
        seg, table = self._windows(U, groups, t)
        rows = window_rows(U, seg, len(table), self.shrinkage)
        if self.n_constraints is not None:
            chosen = sel.Selection("fixed", int(self.n_constraints), [],
                                   f"fixed at {self.n_constraints} per window")
        else:
            chosen = self._rank(X, U, seg, rows, t, derivative)
        self.n_constraints_ = int(chosen.n_constraints)
        self.A_ = rows[:, : self.n_constraints_].copy()
        self.windows_ = table
        self.window_ = self._unit
        self.n_action_ = q
        self.selection_ = {**chosen.as_dict(), "windows": len(table), "per": self.per}
        self.heldout_ = self._held_out(X, U, seg, groups, t, derivative) if self.heldout else None
        return self

    def _one_action(self, U: np.ndarray, groups: np.ndarray | None) -> PerWindow:
        """k = 0 at one action dimension (:data:`~.base.ONE_ACTION`): no rows to place in time, so
        one piece per demonstration (``window_`` None) and the times are not read."""
        table = window_index(groups, None, None, len(U))[1]
        self.windows_ = table if self.TABLE_WIDTH == 2 else table[:, [0, 1, 1]] + [0, 0, 1]
        self.A_ = np.zeros((len(table), 0, 1))
        self.window_ = None
        self.n_action_, self.n_constraints_, self.heldout_ = 1, 0, None
        self.selection_ = {**one_action_selection(), "windows": len(table), "per": "demonstration"}
        return self

    @property
    def per(self) -> str:
        """What one window is, in words ("4-s window", "demonstration")."""
        return "demonstration" if self.window is None else f"{self.window:g}-s window"

    @property
    def local_to(self) -> str:  # type: ignore[override]
        """``demonstration`` (no window) or ``window``."""
        return "demonstration" if self.window is None else "window"

    #: What is kept when the model is fitted on a recording it has not seen.
    KEEPS = ("k", "window", "shrinkage")

    @property
    def new_data_rule(self) -> NewDataRule:
        """Rows fitted per stretch: the rows speak only for the windows they were fitted on."""
        self._check_fitted("A_")
        return NewDataRule(
            "rows fitted per stretch", self.KEEPS,
            f"one constant Ã per {self.per} of the recordings it was fitted on: a demonstration it has "
            f"not seen gets rows fitted on its own {self.per}s by the same rule, "
            f"{self.n_constraints_} row(s) per {self.per} fixed — training figures on those data; a seen "
            "one keeps its fitted rows")

    def applies_to(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None, new_recording: bool = True) -> Applied:
        """Itself when every demonstration of ``groups`` (N,) was fitted here (and the data are
        a part of those recordings), else :meth:`same_kind` fitted on X (N, p), U (N, q) at
        times t (N,) (:attr:`new_data_rule`), with the note saying so."""
        rule = self.new_data_rule
        if not unseen({int(d) for d in np.unique(self.windows_[:, 0])}, groups, new_recording):
            return Applied(self, rule)
        refit = self.same_kind().fit(X, U, groups=groups, t=t)
        what = f"one constraint per {self.per}, {self.n_constraints_} row(s)"
        return Applied(refit, rule, refit_note(what))

    def windows(self) -> Windows | None:
        """The windows in time and their rows (None for one window per demonstration)."""
        self._check_fitted("A_")
        return None if self.window_ is None else Windows(self.per, self.spans(), self.A_)

    @property
    def _unit(self) -> float | None:
        """The length (s) of one step of the table's window index (``window_``): the window."""
        return self.window

    def _windows(self, U: np.ndarray, groups: np.ndarray | None, t: np.ndarray | None
                 ) -> tuple[np.ndarray, np.ndarray]:
        """(window of each sample (N,), table of the windows): fixed in time
        (:func:`~.timeblocks.window_index`)."""
        return window_index(groups, t, self.window, len(U))

    def same_kind(self) -> PerWindow:
        """An unfitted model of the same kind with this one's rows per window (fixed) and no
        held-out figure: what the held-out blocks and a new recording are fitted with."""
        self._check_fitted("A_")
        return clone(self).set_params(n_constraints=self.n_constraints_, heldout=False)

    def _held_out(self, X: np.ndarray, U: np.ndarray, seg: np.ndarray, groups: np.ndarray | None,
                  t: np.ndarray | None, derivative: HowMade) -> dict | None:
        """NPOE of blocks held out inside every window, the model refitted without them (the
        same rows per window), mean and standard error over the folds; None when most windows
        are too short for the blocks and their guard gaps."""
        twin = self.same_kind()
        g = np.zeros(len(U), np.int64) if groups is None else np.asarray(groups)

        def error_of(train: np.ndarray, test: np.ndarray) -> float:
            twin.fit(X[train], U[train], groups=g[train], t=None if t is None else t[train])
            return npoe_error(twin.projection(X[test], groups=g[test], t=None if t is None else t[test]),
                              U[test])

        return inner_heldout(seg, derivative, error_of, "demonstration" if self.window is None else "window")

    @staticmethod
    def _rank(X: np.ndarray, U: np.ndarray, seg: np.ndarray, rows: np.ndarray, t: np.ndarray | None,
              derivative: HowMade) -> sel.Selection:
        """s by the noise rule on every sample's window rows (segments as the demonstrations of
        the second differences), else the ratio rule on the mean squared action along each row."""
        q = U.shape[1]
        ev = nr.Sample.of(X, U, seg, t, derivative).rows_evidence(rows[seg, : q - 1])
        chosen = nr.noise_rank(ev, q - 1, share_rows=nr.SHARE_ROWS)
        if chosen is None:
            chosen = sel.ratio(ev.energy, q - 1, criterion="mean squared action along row k of each window")
            chosen.reason = "the noise rule cannot judge these samples; " + chosen.reason
        return chosen

    def spans(self) -> np.ndarray:
        """[demonstration id, start s, end s] of every window in ``windows_``: (S, 3) (one per
        demonstration without a window: its own times are not kept, start 0, end inf)."""
        self._check_fitted("A_")
        table = self.windows_.astype(float)
        if self.window_ is None:
            return np.column_stack([table[:, 0], np.zeros(len(table)), np.full(len(table), np.inf)])
        return np.column_stack([table[:, 0], table[:, 1] * self.window_, window_ends(table) * self.window_])

    #: Columns of ``windows_``: [demonstration id, j].
    TABLE_WIDTH = 2

    def check_shapes(self) -> None:
        """windows_ (S, 2) integers (a segment table (S, 3) with end > first), A_ (S, s, q) and a
        positive ``window_`` (or None)."""
        win, width = self.windows_, self.TABLE_WIDTH
        if win is None or win.ndim != 2 or win.shape[1] != width or not np.array_equal(win, np.round(win)) \
                or (width == 3 and not (win[:, 2] > win[:, 1]).all()):
            raise self._shape_error("windows_")
        step = self.window_
        if self.A_ is None or self.A_.shape != (len(win), self.n_constraints_, self.n_action_) or (
                step is not None and not (isinstance(step, int | float) and step > 0)):
            raise self._shape_error("A_")
        super().check_shapes()

    # -- prediction ----------------------------------------------------------------------
    def window_of(self, X: np.ndarray, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray:
        """Index (N,) into ``windows_`` of each sample: its own window, else the nearest fitted
        window of its demonstration (InputError for a demonstration not seen in ``fit``)."""
        self._check_fitted("A_")
        return nearest_window(self.windows_, self.window_, len(self._check_states(X)), groups, t)

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã of each sample's window: (N, s, q)."""
        return self.A_[self.window_of(X, groups, t)]

