"""The manifold of the states in the phases where they come back over their ground, free elsewhere
(a surface worked in phases: approach in free space, strokes on the surface, retract).

Where: the *runs* are the samples that come back over their own ground — each sample with two
other passes of its demonstration within PHASE_RADIUS × that demonstration's RMS spread, runs of at
least MIN_RUN_SHARE of it (:func:`~.geometry.contact_runs`): strokes on a table come back over their
ground, an approach and a retract do not. Each run r lies at its own level ℓ_r = median of h over
it; the constraint holds at a sample x of demonstration d when h(x) is within TOL × σ of the level
of one of d's runs, for every level function (σ (k,): the RMS of h − ℓ_r over the runs' samples at
fit, ``spread_``) — the whole of the contact, also where a stroke turns without coming back. All of
it is read from the positions alone: the same at any rate, time or length unit, frame and order.

What: k level functions h_j(x) = w_jᵀφ(x) (:class:`~.manifold.ManifoldConstraint`, the same
generalised eigenproblem), made constant along every phase, each phase at its own level:

    Ã(x) = ∇h(x) orthonormalised   in a phase,      no rows elsewhere,
    Ñ(x) = I − ÃᵀÃ                 in a phase,      Ñ = I elsewhere.

A velocity-based model of the same phases (:class:`~.stretches.ConstraintInStretches`) reads the
rows from the motion in short blocks; a hand's tremor or a compliant contact moves along the normal
far above the sensor's noise there, while the positions' level sets do not accumulate it.

New data: the learnt level functions carry over; the phases of the data given are found again from
their positions by the same rule (the rule of every recording, seen or not).

Shapes: X (N, q) positions, U (N, q) their velocities (shape only), groups (N,) demonstration ids.
"""

from __future__ import annotations

import hashlib
from typing import ClassVar

import numpy as np

from ccl_cli.dataset import group_rows
from ccl_cli.errors import InputError
from ccl_cli.learn.constraint.base import NewDataRule
from ccl_cli.learn.constraint.geometry import MIN_RUN_SHARE, PHASE_RADIUS, contact_runs
from ccl_cli.learn.constraint.manifold import ManifoldConstraint
from ccl_cli.learn.params import parameters

#: A sample holds when each level is within TOL × the levels' RMS spread inside the runs of the level
#: of a run of its demonstration (simulated wipes and a tremoring hand: 0.92–0.97 of the samples
#: labelled as the truth at 3–6, docs/auto.md).
TOL = 3.0
#: The phases of this many data sets kept per model, the least recently asked for dropped
#: (:meth:`ManifoldInPhases._runs`): the training and the held-out part, each asked for by the
#: evidence, the scores and the report, between bounded samples of them.
RUNS_KEPT = 4


def run_levels(H: np.ndarray, runs: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """The level of each run (the median of its levels H (N, k) over its samples, runs (N,) ≥ 0)
    and each sample's run index into them: ((R, k), (N,))."""
    ids, inverse = np.unique(runs, return_inverse=True)
    order = np.argsort(inverse, kind="stable")
    cuts = np.flatnonzero(np.diff(inverse[order])) + 1
    levels = np.array([np.median(H[part], axis=0) for part in np.split(order, cuts)]).reshape(len(ids), -1)
    return levels, inverse.ravel()


@parameters
class ManifoldInPhases(ManifoldConstraint):
    """k level functions of the states that hold in the phases where the demonstrations come back
    over their ground, no constraint elsewhere (module docstring).

    Args:
        family, n_constraints, tolerance: as :class:`~.manifold.ManifoldConstraint`'s, fitted on
            the phases (each run of samples its own stretch).

    Attributes:
        those of :class:`~.manifold.ManifoldConstraint`; spread_ (k,) σ, the RMS of each level
        about its run's level over the runs (length units); share_, the share of the samples
        where the constraint holds.
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {**ManifoldConstraint._fitted_attributes,
                                                    "spread_": "array", "share_": "value"}

    #: Ñ switches between I − ÃᵀÃ and I from phase to phase.
    @property
    def varies_with_state(self) -> bool:  # type: ignore[override]
        return True

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: object = None) -> ManifoldInPhases:
        """Find the phases of the states X (N, q) of demonstrations ``groups`` and fit the level
        functions on them; U (N, q) gives the shape only; ``t`` and ``derivative`` are not read.
        InputError when no phase is found."""
        X, U = self._prepare_fit(X, U)
        g = np.zeros(len(X), np.int64) if groups is None else np.asarray(groups)
        self._runs_of: dict[bytes, np.ndarray] = {}
        runs = self._runs(X, g) if len(X) else np.zeros(0, np.int64)
        inside = runs >= 0
        if not inside.any():
            raise InputError("no phase of the states comes back over its ground: no surface in phases "
                             "to learn")
        super().fit(X[inside], U[inside], groups=runs[inside])
        H = self.levels(X)
        levels, which = run_levels(H[inside], runs[inside])
        floor = np.finfo(float).eps * self.scale_
        self.spread_ = np.maximum(np.sqrt(((H[inside] - levels[which]) ** 2).mean(0)), floor)
        self.share_ = float(self._on(H, g, runs).mean())
        self.selection_ = {**self.selection_, "reason": f"{self.selection_['reason']}; {self.summary()}"}
        return self

    def holds(self, X: np.ndarray, *, groups: np.ndarray | None = None,
              t: np.ndarray | None = None) -> np.ndarray:
        """Whether each sample (N,) lies in a phase of the data given, found from their positions."""
        self._check_fitted("weights_")
        X = self._check_states(X)
        if self.n_constraints_ == 0 or not len(X):
            return np.zeros(len(X), dtype=bool)
        g = np.zeros(len(X), np.int64) if groups is None else np.asarray(groups)
        return self._on(self.levels(X), g, self._runs(X, g))

    def _runs(self, X: np.ndarray, groups: np.ndarray) -> np.ndarray:
        """:func:`~.geometry.contact_runs` of X (N, q) and ``groups`` (N,), read-only: those of
        the last :data:`RUNS_KEPT` data sets asked for are kept, by the contents of X and groups (the
        holds of the training and the held-out part are asked for several times a run, 0.3 s
        each at 6·10⁵ samples, against 15 ms for the key)."""
        key = hashlib.blake2b(digest_size=16)
        for a in (X, groups):
            a = np.ascontiguousarray(a)
            key.update(f"{a.dtype.str}{a.shape}".encode())
            key.update(a.data)
        digest = key.digest()
        kept = vars(self).setdefault("_runs_of", {})
        runs = kept.pop(digest, None)
        if runs is None:
            runs = contact_runs(X, groups)
            runs.flags.writeable = False
            while len(kept) >= RUNS_KEPT:
                kept.pop(next(iter(kept)))
        kept[digest] = runs  # the most recent last
        return runs

    def _on(self, H: np.ndarray, groups: np.ndarray, runs: np.ndarray) -> np.ndarray:
        """Whether each sample's levels H (N, k) are within TOL × spread_ of the level of a run
        (runs (N,), −1 outside) of its demonstration: (N,)."""
        on = np.zeros(len(H), dtype=bool)
        inside = runs >= 0
        if not inside.any():
            return on
        levels, which = run_levels(H[inside], runs[inside])
        demo_of_run = np.empty(len(levels), dtype=groups.dtype)
        demo_of_run[which] = groups[inside]
        of_demo = dict(zip(*group_rows(demo_of_run), strict=True))
        for d, rows in zip(*group_rows(groups), strict=True):
            if d in of_demo:
                near = np.abs(H[rows][:, None, :] - levels[of_demo[d]][None]) <= TOL * self.spread_
                on[rows] = near.all(-1).any(-1)
        return on

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None, t: np.ndarray | None = None,
                   k: int | None = None) -> np.ndarray:
        """Ã: the orthonormalised gradients of the level functions in a phase, rows of zeros
        elsewhere: (N, k, q)."""
        on = self.holds(X, groups=groups, t=t)
        A = super().constraint(X, k=k)
        return np.where(on[:, None, None], A, 0.0)

    def constant_rows(self) -> np.ndarray | None:
        """The rows (k, q) of a ``linear`` model where it holds, else None."""
        if self.family != "linear":
            return None
        self._check_fitted("weights_")
        return super().constraint(self.centre_[None])[0]

    def check_shapes(self) -> None:
        """Those of :class:`~.manifold.ManifoldConstraint`; spread_ (k,) positive and finite, share_ in
        [0, 1]."""
        spread = getattr(self, "spread_", None)
        if spread is None or np.shape(spread) != (self.n_constraints_,) or \
                not (np.isfinite(spread).all() and (np.asarray(spread) > 0).all()):
            raise self._shape_error("spread_")
        if not (isinstance(self.share_, float | int) and 0 <= self.share_ <= 1):
            raise self._shape_error("share_")
        super().check_shapes()

    @property
    def new_data_rule(self) -> NewDataRule:
        """Phases found again: the level functions kept, where they hold found on the data given."""
        return NewDataRule(
            "phases found again", ("levels", "k"),
            f"its {self.n_constraints_} level function(s) describe a surface, not where a recording touches "
            "it: on any recording they hold where the states lie at the level of a run of samples that "
            f"comes back over its own ground (two other passes within {PHASE_RADIUS:g} × the "
            f"demonstration's spread, runs of at least {100 * MIN_RUN_SHARE:g} % of it; within {TOL:g} × "
            "the learnt spread of the levels), found from its positions")

    def summary(self) -> str:
        """Where the constraint holds, in words."""
        return (f"k = {self.n_constraints_} ({self.family} level functions) in the phases that come back "
                f"over their ground ({100 * self.share_:.0f} % of the samples); free motion elsewhere")
