"""learn-a's default: the model class and the number of constraints chosen by held-out
evidence, "no constraint" included ("auto", issue 17).

Candidates, simplest first — the order in which the one-standard-error rule prefers them:

==============  ===========================================================================
``none``        Ñ = I: no constraint (k = 0)
``nhat``        one constant A for all the data (§3.1)
``per_demo``    one constant A per demonstration (:class:`~.windows.PerWindow`, window None)
``per_segment`` one constant A per segment of each demonstration, cut where it changes
                (:class:`~.segments.PerSegment`)
``per_window``  one constant A per W-s window of each demonstration (PerWindow)
``alpha_linear`` A(x) whose angles are linear in x (§3.2, linear basis)
``alpha``       A(x) whose angles are linear in alpha's RBF features (§3.2, 25 centres;
                states of at most MAX_RBF_STATES dimensions)
``lambda``      A(x) = Λ(x)Φ(x), when features Φ are given (§3.3)
``linear``      A(x) = W Φ_A(x), when regressors are given (§3.5)
``stretches``   one constant A in the stretches where it holds, none elsewhere
                (:class:`~.stretches.ConstraintInStretches`; tried only when no candidate
                above finds a constraint on held-out data)
==============  ===========================================================================

The order is that of how far a model's claim reaches beyond the samples it was fitted on:
``none`` claims nothing; ``nhat`` one direction shared by every sample; a per-demonstration or
per-window model one direction per stretch of the recording, nothing about other stretches
(fewer stretches first); a state-dependent model a field A(x) over the state space, which
also predicts states never visited (the linear field before the RBF one); ``lambda`` and
``linear`` such a field built on features the user chose, right only when those features are,
so they must earn their place by held-out evidence over the field learnt without them.

Evidence, from one cross-validation
-----------------------------------
1. *Held-out rows.* Each candidate (but ``none``) is fitted with m rows (m = q − 1, or fewer:
   ``max_constraints``, r − 1 for lambda) on every training fold, and its rows at the fold's
   held-out samples are kept: every sample gets the rows of a model that did not see it.
   Global candidates use :func:`~ccl_cli.learn.model_selection.make_folds` (held-out
   demonstrations, or contiguous time blocks of one recording); a per-demonstration or
   per-window model can only speak for its own stretch, so it is tested on blocks held out
   *inside* each window / demonstration (:func:`~ccl_cli.learn.model_selection.inner_folds`),
   and is not tried when its windows are too short for that.
2. *Rank k of each candidate* by the noise-aware rule (:mod:`.noise_rank`) on those held-out
   rows: row j is a constraint when the held-out motion along it is at the noise level the
   data show (second differences; through the derivative filter when the velocities were
   derived), or a negligible share of the motion. A model that overfits its training folds
   does not gain rows: its rows move on held-out data.
   A model per stretch may claim no more rows than the best global model (or one when no
   global model finds any): within a short stretch the motion often takes fewer than q − k
   directions, and such a model would call every direction it did not take a constraint.
3. *Class.* k* = the largest rank any candidate reaches — every candidate of rank k* explains
   k* directions of held-out motion as noise, which no candidate of smaller rank does. The
   candidates of rank k* are then scored on the same held-out samples — the blocks inside
   windows when a per-stretch model is among them (the global ones fitted again without those
   blocks), else their common folds — by their held-out NPOE (§6) with k* rows, comparable
   since each removes k* directions. The simplest whose mean exceeds the best's by at most
   one standard error of their per-fold differences (a paired comparison) wins. For k* = 0
   that is ``none``.

4. *A constraint in stretches.* When every candidate above says k = 0 — a whole wiping
   recording moves along the table's normal during approach and retract — ``stretches`` asks
   whether rows learnt on the training folds are quiet in at least
   :data:`~.stretches.MIN_SHARE` of the held-out moving time, the noise rule agreeing on the
   held-out samples it claims (:func:`~.stretches.held_out`). If so it wins with its rank;
   Ñ = I − RᵀR where it holds, I elsewhere.

Why not held-out NPOE across ranks: Ñ = I has NPOE 0, so NPOE alone always prefers fewer
constraints; and a flexible model can lower the NPOE of one row by turning it towards
whatever direction its training data happen not to move along (a row in the plane,
perpendicular to the local strokes, instead of the normal). The noise level is what tells a
constraint from a direction the motion merely did not take, and held-out rows are what keep
a flexible model from fitting its own noise.

When the samples are not trajectories in time (the noise rule cannot judge: the actions'
total variance is below MIN_SNR × their noise), each candidate's rank falls back to the
``ratio`` rule on its held-out energies (at least one constraint). With too few samples to
cross-validate, nhat is fitted with the noise rule on its own rows.

Above :data:`CHOICE_ROWS` samples the candidates are tried and scored on a bounded, seeded
sample of whole demonstrations (or contiguous blocks of long ones, each acting as a
demonstration), counted in rows: the work of the choice does not grow with N, and only the
winner is fitted on all the samples (``selection_["subset"]`` says what was taken). The states'
geometry reads its own bounded sample (:func:`.geometry.evidence_rows`).

Nothing here reads a clock: the same data and parameters give the same model.
"""

from __future__ import annotations

from typing import Annotated, Any, ClassVar

import numpy as np

from ccl_cli.dataset import HowMade
from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.learn import blas
from ccl_cli.learn import model_selection as ms
from ccl_cli.learn.constraint import evidence as ev
from ccl_cli.learn.constraint import force_evidence, sure
from ccl_cli.learn.constraint import geometry as geo
from ccl_cli.learn.constraint import noise_rank as nr
from ccl_cli.learn.constraint.alpha import StateDependentConstraint
from ccl_cli.learn.constraint.base import (
    ONE_ACTION,
    Applied,
    ConstraintModel,
    NewDataRule,
    Windows,
    check_rows_asked,
)
from ccl_cli.learn.constraint.lambda_ import FeatureSpec, KnownFeatureConstraint, make_features
from ccl_cli.learn.constraint.linear import LinearConstraint
from ccl_cli.learn.constraint.manifold import ManifoldConstraint
from ccl_cli.learn.constraint.nhat import StateIndependentConstraint
from ccl_cli.learn.constraint.none import NO_CONSTRAINT, NoConstraint
from ccl_cli.learn.constraint.per_demo import PerDemonstration
from ccl_cli.learn.constraint.segments import PerSegment
from ccl_cli.learn.constraint.stretches import BLOCK_S, MIN_SHARE, ConstraintInStretches
from ccl_cli.learn.constraint.stretches import held_out as stretches_held_out
from ccl_cli.learn.constraint.windows import PerWindow, window_index
from ccl_cli.learn.defaults import N_FOLDS, WINDOW_S
from ccl_cli.learn.params import (
    Interval,
    MaxConstraints,
    NConstraints,
    NFolds,
    Regressors,
    Seconds,
    SeedParams,
    parameters,
)

#: Every candidate, simplest first (module docstring).
CANDIDATES = ("none", "manifold", "nhat", "per_demo", "per_segment", "per_window", "alpha_linear", "alpha",
              "lambda", "linear", "stretches")
#: The RBF alpha candidate is tried up to this state dimension: its 25 centres cover no more
#: (beyond it: alpha with linear angles, or lambda with the arm's own features).
MAX_RBF_STATES = 3
#: Above this many samples the candidates are chosen on a seeded sample of about this many
#: (whole demonstrations or contiguous blocks), and only the winner is fitted on all of them.
CHOICE_ROWS = ms.TUNE_MAX_ROWS
#: The candidates whose rank bounds the rows the costly alpha fits need (one more than theirs).
_CHEAP = ("nhat", "per_demo", "per_window", "per_segment")


@parameters
class AutoConstraint(ConstraintModel, SeedParams):
    """The constraint model and its number of rows chosen by held-out evidence (module docstring).

    Args:
        candidates: names from :data:`CANDIDATES` to try (None: all that apply — ``lambda``
            needs ``features``, ``linear`` needs ``regressors``, ``per_window`` the sample times).
        window: window length (s) of the ``per_window`` candidate.
        features: Φ of the ``lambda`` candidate (a built-in arm, ``{arm, rows}`` or a callable).
        regressors: regressors of the ``linear`` candidate (``identity``, ``rbf``, ``polynomial``).
        n_constraints: fix k; the class is then chosen at that k.
        max_constraints: at most this many rows (default q − 1).
        cv_folds: folds of the cross-validation.
        gap: samples dropped from training at each held-out boundary (None: the derivative
            window when the actions were derived, else
            :data:`~ccl_cli.learn.model_selection.RECORDED_GAP`).
        seed: of the folds and of every candidate.

    Attributes:
        model_: the winner refitted on all the data (a :class:`NoConstraint` for k = 0);
        n_constraints_, selection_ (rule "auto", the reason, ``candidates``: a row per
        candidate — class, model, k, held-out error and SE, noise ratios, folds, chosen,
        reason), heldout_ (the winner's held-out NPOE: {error, mean, se, per_fold, folds}; None
        for k = 0), n_action_, n_features_in_. Other learnt attributes (``A_``, ``basis_``, ...)
        are the winner's.
    """

    _fitted_attributes: ClassVar[dict[str, str]] = {}  # saved as its winner (ccl_cli.models)
    candidates: list[str] | None = None
    window: Seconds = WINDOW_S
    features: FeatureSpec | None = None
    regressors: Regressors | None = None
    n_constraints: NConstraints = None
    max_constraints: MaxConstraints = None
    cv_folds: NFolds = N_FOLDS
    gap: Annotated[int, Interval(0, 1_000_000)] | None = None

    # -- the protocol: answered as the model it chose --------------------------------------
    @property
    def chosen_(self) -> ConstraintModel:
        """The model it chose, fitted on all the data (``selection_["reason"]`` says why)."""
        self._check_fitted("model_")
        return self.model_

    @property
    def local_to(self) -> str | None:  # type: ignore[override]
        return self.chosen_.local_to

    @property
    def varies_with_state(self) -> bool:  # type: ignore[override]
        return self.chosen_.varies_with_state

    @property
    def new_data_rule(self) -> NewDataRule:
        return self.chosen_.new_data_rule

    def applies_to(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None, new_recording: bool = True) -> Applied:
        """As the model it chose applies (its :attr:`new_data_rule`)."""
        return self.chosen_.applies_to(X, U, groups=groups, t=t, new_recording=new_recording)

    def constant_rows(self) -> np.ndarray | None:
        return self.chosen_.constant_rows()

    def windows(self) -> Windows | None:
        return self.chosen_.windows()

    def models_by_demonstration(self) -> dict[int, ConstraintModel] | None:
        return self.chosen_.models_by_demonstration()

    def __getattr__(self, name: str) -> Any:
        """Learnt attributes (``..._``) of the winner, e.g. ``A_`` or ``basis_``."""
        if name.endswith("_") and not name.startswith("_") and "model_" in vars(self):
            return getattr(vars(self)["model_"], name)
        raise AttributeError(f"{type(self).__name__!r} object has no attribute {name!r}")

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """The winner's Ã(X): (N, p) → (N, k, q) (k = 0: no rows)."""
        return self.chosen_.constraint(X, groups=groups, t=t)

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """The winner's Ñ(X): (N, p) → (N, q, q)."""
        return self.chosen_.projection(X, groups=groups, t=t)

    def task_part(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray | None:
        """The winner's ṽ (N, q), or None."""
        return self.chosen_.task_part(X, groups=groups, t=t)

    def holds(self, X: np.ndarray, *, groups: np.ndarray | None = None,
              t: np.ndarray | None = None) -> np.ndarray:
        return self.chosen_.holds(X, groups=groups, t=t)

    # -- fitting --------------------------------------------------------------------------
    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None, force: np.ndarray | None = None
            ) -> AutoConstraint:
        """Choose and fit the constraint model: from the states and the velocities
        (:meth:`_fit`), then — with ``force`` (N, 3), the base-frame force of a force/torque
        sensor — weighed against the contact the force shows (:mod:`.force_evidence`)."""
        self._fit(X, U, groups=groups, t=t, derivative=derivative)
        if force is not None:
            force_evidence.weigh(self, np.asarray(X, float), np.asarray(U, float), groups, t, force)
        return self

    def _fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
             t: np.ndarray | None = None, derivative: HowMade = None) -> AutoConstraint:
        """Choose and fit the constraint model from the states and the velocities.

        Args:
            X (N, p), U (N, q): states and actions, in time order within each demonstration.
            groups (N,): demonstration ids (None: one demonstration).
            t (N,): sample times in seconds (None: ``per_window`` is not tried and the noise
                is read from the actions in sample order).
            derivative: how U was made — the readers' ``{"window", "order"}`` when derived
                from the positions X by their local polynomial, False when recorded, None when
                not known (the larger of the two noise estimates,
                :func:`~ccl_cli.learn.constraint.noise_rank.row_evidence`).

        One action dimension (q = 1): no constraint (k = 0, :data:`~.base.ONE_ACTION`), no
        candidate tried.
        """
        X, U = self._prepare_fit(X, U)
        n, q = U.shape
        check_rows_asked(q, self.n_constraints)
        if t is not None:
            t = np.asarray(t, dtype=float)
            if t.shape != (n,):
                raise InputError(f"t must hold one time per sample, ({n},), got {t.shape}")
        self.n_action_ = q
        self.geometry_ = None
        if q == 1:
            self._one_action(X, U, groups)
            return self
        data = ev.Sample.of(X, U, groups, t, derivative)
        derived = data.derived
        if self._geometry(data, derivative):
            return self
        gap = self.gap if self.gap is not None else int(derived.window) if derived else ms.RECORDED_GAP
        choice, subset = self._choice_sample(data)
        try:
            folds = ms.make_folds(choice.groups, len(choice.U), self.cv_folds, self.seed, gap)
        except InputError as exc:
            self._fit_without_cv(data, exc.message)
            return self
        with blas.threads(blas.RUN_THREADS):  # many small fits: one BLAS thread
            tried, skipped = self._cross_validate(choice, folds, gap)
            self._choose(choice, tried, skipped, data)
        if subset:
            self.selection_["subset"] = subset
        return self

    def _choice_sample(self, data: ev.Sample) -> tuple[ev.Sample, str]:
        """The samples the candidates are chosen on (every candidate's held-out rows, rank and
        NPOE): all of them up to :data:`CHOICE_ROWS`; above, a bounded, seeded sample of whole
        demonstrations or contiguous blocks (:func:`~ccl_cli.learn.model_selection.tuning_subset`;
        blocks of one recording act as its demonstrations) — the losing candidates never see
        all N — and a sentence saying what was taken ("" for all). The winner is fitted on all."""
        sample, _, note = self._bounded(data)
        return sample, note.replace("searched", "candidates chosen")

    def _bounded(self, data: ev.Sample) -> tuple[ev.Sample, np.ndarray | None, str]:
        """:meth:`_choice_sample` with the rows of ``data`` it took (None: all)."""
        found = ms.tuning_subset(data.groups, len(data.U), int(self.seed), CHOICE_ROWS)
        if found is None:
            return data, None, ""
        rows, groups, note = found
        return ev.Sample(data.X[rows], data.U[rows], groups, None if data.t is None else data.t[rows],
                         data.derived, data.recorded), rows, note

    def _geometry(self, data: ev.Sample, derivative: HowMade) -> bool:
        """The states' own geometry first (:mod:`.geometry`), when the actions are their derivative:
        if it shows k > 0 constraints, the winner is the manifold that shows them (True);
        otherwise (False) the velocities decide, and ``geometry_`` keeps what the states showed."""
        if (self.candidates is not None and "manifold" not in self.candidates) or self.n_constraints == 0:
            return False
        X, U = data.X, data.U
        moving, why = geo.kinematic(X, U, data.groups, data.t, derivative)
        if not moving:
            self.geometry_ = {"tried": False, "reason": why}
            return False
        found = geo.decide(X, data.groups, only_k=self.n_constraints, max_k=self.max_constraints, t=data.t)
        self.geometry_ = {"tried": True, "k": found.k, "reason": f"{why}; {found.reason}",
                          "models": [t.row(t is found.winner) for t in found.tried],
                          "returns": {str(k): v for k, v in found.revisits.items()}}
        if found.k == 0:
            return False
        w = found.winner
        self.model_ = self._manifold_model(w, found.k, data)
        self.n_constraints_ = found.k
        scope = ("one per demonstration" if w.scope == "per_demo" else
                 "one family, each demonstration at its own offset")
        label = f"the manifold of the states ({w.basis}, {scope})"
        self.heldout_ = None
        rows = [{**ev.not_tried("none", ""), "model": "no constraint (Ñ = I)", "k": 0, "chosen": False,
                 "reason": f"the states show {found.k} constraint(s)"}]
        rows += [{**ev.not_tried("manifold", ""), "model": f"manifold: {t.basis} ({t.scope})", "k": t.k,
                  "error": t.measure,
                  "heldout_error": t.worst, "chosen": t is w, "rank_reason": t.why,
                  "reason": ("chosen: " if t is w else "") + ("holds" if t.holds else "does not hold") +
                  f" ({t.worst:.3g} against {t.limit:g})"} for t in found.tried]
        rows += [ev.not_tried(c, "the states' geometry decided") for c in CANDIDATES
                 if c not in ("none", "manifold")]
        chosen = ("per_demo_task" if w.scope == "per_demo_task" else
                  "stretches" if w.scope == "phases" and data.t is not None else
                  "manifold" if w.basis != "linear" or w.scope == "phases" else
                  "nhat" if w.scope == "global" else
                  "per_demo" if data.t is not None and w.measure != "shape residual" else "manifold")
        self.selection_ = {"rule": "auto", "n_constraints": found.k, "model": label, "chosen": chosen,
                           "decided_by": "states",
                           "reason": f"{found.k} constraint(s): {found.reason}" + (
                               f": {self.model_.summary()}" if hasattr(self.model_, "summary") else ""),
                           "values": [float(v) for v in w.drift],
                           "criterion": f"{w.measure} of level function k (RMS along the demonstrations / "
                                        "RMS spread)",
                           "candidates": rows, "geometry": self.geometry_}
        self.selection_["sure"] = self._sure_of_states(data, w, found.k)
        self.model_.selection_ = {**self.selection_, "winner_selection": self.model_.selection_}
        return True

    def _sure_of_states(self, data: ev.Sample, winner: geo.Tried, k: int) -> dict[str, Any]:
        """How sure (:mod:`.sure`): the model of the states' manifold fitted again without each
        fold — whole demonstrations, or blocks inside each one for a model per demonstration or
        stretch — its rows at the held-out samples against the final ones, and k ± 1. Above
        :data:`CHOICE_ROWS` samples the folds are those of the bounded sample the velocity
        candidates would be chosen on (:meth:`_bounded`): the cone's work does not grow with N."""
        q = data.U.shape[1]
        derived = data.derived
        everything = data
        data, taken, note = self._bounded(data)
        gap = self.gap if self.gap is not None else int(derived.window) if derived else ms.RECORDED_GAP

        def refit(idx: np.ndarray) -> ConstraintModel:
            return self._manifold_model(winner, k, sure.part(data, idx), heldout=False)

        try:
            if self.model_.is_local:
                seg = np.unique(data.groups, return_inverse=True)[1].ravel()
                folds = ms.inner_folds(seg, self.cv_folds, gap, "demonstration")
            else:
                folds = ms.make_folds(data.groups, len(data.U), self.cv_folds, self.seed, gap)
            held = sure.held_out_rows(refit, data.X, data.groups, data.t, k, folds.pairs)
        except (ValueError, np.linalg.LinAlgError, FloatingPointError) as exc:
            why = f"no held-out fits: {getattr(exc, 'message', None) or exc}"
            return sure.summary(None, None, "", self.selection_, q, why)
        if taken is None:
            final = self.model_.constraint(data.X, groups=data.groups, t=data.t)
        else:  # the final model at the rows taken, as the demonstrations it was fitted on
            final = self.model_.constraint(everything.X[taken], groups=everything.groups[taken],
                                           t=None if everything.t is None else everything.t[taken])
        found = sure.summary(final, held, folds.reason, self.selection_, q)
        return {**found, "subset": note.replace("searched", "cone read")} if note else found

    def _manifold_model(self, winner: geo.Tried, k: int, data: ev.Sample, heldout: bool = True
                        ) -> ConstraintModel:
        """The model of the manifold the states showed, with k rows, fitted on all the data. Flat
        families (planes, and lines shared by every demonstration: constant rows) take their rows
        from the velocities (§3.1, one constant A, per demonstration when each has its own
        surface): every part of the motion weighs by how much it moves, which a tilting or bowing
        surface does not skew the way the spread of the positions does; a line or circle in each
        demonstration, spheres and quadrics take the gradients of their levels (a line's
        direction is best read off its whole extent). ``heldout``: a model per demonstration
        also measures its held-out NPOE."""
        X, U, g = data.X, data.U, data.groups
        if winner.scope == "per_demo_task":  # its own rows and task part in each: §3.5 with a task term
            return PerDemonstration(LinearConstraint(regressors="identity", task=True, n_constraints=k),
                                    heldout=heldout).fit(X, U, groups=g, derivative=data.derivative)
        if winner.scope == "phases" and data.t is not None:  # the rows where they hold, found in time
            return ConstraintInStretches(block=BLOCK_S, n_constraints=k).fit(
                X, U, groups=g, t=data.t, derivative=data.derivative)
        if winner.basis == "linear" and winner.scope == "global":
            return StateIndependentConstraint(n_constraints=k, seed=self.seed).fit(X, U, groups=g)
        if winner.basis == "linear" and data.t is not None and winner.measure != "shape residual":
            return PerWindow(window=None, n_constraints=k, heldout=heldout).fit(
                X, U, groups=g, t=data.t, derivative=data.derivative)
        est = ManifoldConstraint(family=winner.basis, n_constraints=k)
        if winner.scope in ("global", "phases"):
            return est.fit(X, U, groups=g)
        return PerDemonstration(est, heldout=heldout).fit(X, U, groups=g, derivative=data.derivative)

    def _candidates(self, data: ev.Sample, gap: int) -> tuple[list[ev.Candidate], list[dict[str, Any]]]:
        """The candidates to try, simplest first, and the table rows of those not tried."""
        names = list(CANDIDATES) if self.candidates is None else list(self.candidates)
        unknown = [c for c in names if c not in CANDIDATES]
        if unknown:
            raise ConfigError(f"AutoConstraint: unknown candidate {unknown[0]!r} (candidates: "
                              f"{', '.join(CANDIDATES)})")
        q, p = data.U.shape[1], data.X.shape[1]
        m = min(self.max_constraints or q - 1, q - 1)
        seed = int(self.seed)
        out: list[ev.Candidate] = []
        skipped: list[dict[str, Any]] = []
        for name in sorted(set(names) - {"none", "manifold", "stretches"}, key=CANDIDATES.index):
            if name == "nhat":
                out.append(ev.Candidate(name, "one constant A (nhat)", lambda k: StateIndependentConstraint(
                    n_constraints=max(k, 1), seed=seed), m))
            elif name in ("per_demo", "per_window", "per_segment"):
                found = self._per_stretch(name, data, gap, m)
                (out if isinstance(found, ev.Candidate) else skipped).append(found)
            elif name == "alpha" and p > MAX_RBF_STATES:
                why = (f"{p} state dimensions: RBF centres cover at most {MAX_RBF_STATES} "
                       "(here: alpha_linear, or lambda with features)")
                skipped.append(ev.not_tried(name, why))
            elif name.startswith("alpha"):
                basis = {"basis": "linear"} if name == "alpha_linear" else {}
                label = f"A(x), angles {'linear in x' if basis else 'on RBF features'} (alpha)"
                out.append(ev.Candidate(name, label, lambda k, b=basis: StateDependentConstraint(
                    **b, tune=False, n_constraints=max(k, 1), seed=seed), m))
            elif name == "lambda" and self.features is None:
                skipped.append(ev.not_tried(name, "needs features (e.g. features: arm7)"))
            elif name == "lambda":
                r = make_features(self.features)(data.X[:1]).shape[1]
                out.append(ev.Candidate(name, "A(x) = Λ(x)Φ(x) (lambda)", lambda k: KnownFeatureConstraint(
                    features=self.features, tune=False, n_constraints=max(k, 1), seed=seed), min(m, r - 1)))
            elif name == "linear" and self.regressors is None:
                skipped.append(ev.not_tried(name, "needs regressors (identity, rbf or polynomial)"))
            elif name == "linear":
                out.append(ev.Candidate(name, f"A(x) = W Φ_A(x), {self.regressors} regressors (linear)",
                                        lambda k: LinearConstraint(regressors=self.regressors, tune=False,
                                                                   n_constraints=max(k, 1), seed=seed), m))
        return out, skipped

    def _per_stretch(self, name: str, data: ev.Sample, gap: int, m: int) -> ev.Candidate | dict[str, Any]:
        """The per-demonstration or per-window candidate, or the row saying why it is not tried."""
        window = None if name == "per_demo" else float(self.window)
        if window is not None and data.t is None:
            return ev.not_tried(name, "needs the sample times")
        seg, table = window_index(data.groups, data.t, window, len(data.U))
        what = "demonstration" if window is None else f"{window:g}-s window"
        n_demos = len(np.unique(data.groups))
        if len(table) == 1:
            return ev.not_tried(name, "one demonstration in one stretch: the same as nhat")
        if len(table) == n_demos and name == "per_window":
            return ev.not_tried(name, f"every demonstration fits in one {what}: the same as per_demo")
        need = self.cv_folds * (2 * gap + ms.MIN_BLOCK)
        counts = np.bincount(seg)
        if (counts[seg] >= need).mean() < 0.5:
            return ev.not_tried(name, f"most {what}s hold fewer than {need} samples, too few for "
                                f"{self.cv_folds} held-out blocks inside each with guard gaps of {gap}")
        if name == "per_segment":  # tested on the same blocks as per_window, for a paired comparison
            return ev.Candidate(name, "one constant A per segment, cut where it changes",
                                lambda k: PerSegment(n_constraints=k, heldout=False), m, seg, what)
        label = "one constant A per demonstration" if window is None else f"one constant A per {what}"
        return ev.Candidate(name, label, lambda k: PerWindow(window=window, n_constraints=k, heldout=False),
                            m, seg, what)

    def _cross_validate(self, data: ev.Sample, folds: ms.Folds, gap: int
                        ) -> tuple[list[ev.Tried], list[dict[str, Any]]]:
        """Every candidate's held-out rows and rank (:mod:`.evidence`), simplest first."""
        cands, skipped = self._candidates(data, gap)
        tried: list[ev.Tried] = []
        cheap_k = 0
        for cand in cands:
            item = ev.Tried(cand, folds if cand.segments is None else ms.inner_folds(
                cand.segments, self.cv_folds, gap, cand.what))
            m = cand.max_rows
            if cand.name.startswith("alpha"):  # the costly fits: as many rows as can matter
                m = min(m, max(cheap_k, self.n_constraints or 0) + 1)
            try:
                while True:
                    item.rows = ev.held_out_rows(cand, item.folds, m, data)
                    ev.rank(item, m, data)
                    if not (cand.name.startswith("alpha") and item.k == m < cand.max_rows):
                        break
                    m += 1  # every row so far is a constraint: one more may be
            except (LearningError, np.linalg.LinAlgError, FloatingPointError) as exc:
                item.k, item.note = None, f"failed: {getattr(exc, 'message', None) or exc}"
            if cand.name in _CHEAP and item.k is not None:
                cheap_k = max(cheap_k, item.k)
            tried.append(item)
        ev.cap_local(tried)
        if self.candidates is None or "stretches" in self.candidates:
            found = self._stretches(data, folds, tried)
            (tried if isinstance(found, ev.Tried) else skipped).append(found)
        return tried, skipped

    def _stretches(self, data: ev.Sample, folds: ms.Folds, tried: list[ev.Tried]
                   ) -> ev.Tried | dict[str, Any]:
        """The constraint in stretches (:mod:`.stretches`), tried when no other candidate finds a
        constraint on held-out data: its rank and held-out NPOE from
        :func:`~ccl_cli.learn.constraint.stretches.held_out` on the global folds."""
        name = "stretches"
        k_other = max([c.k for c in tried if c.k is not None], default=0)
        if k_other > 0:
            return ev.not_tried(name, f"{k_other} constraint(s) hold on held-out data all along")
        if self.n_constraints is not None:
            return ev.not_tried(name, "n_constraints is fixed")
        if data.t is None:
            return ev.not_tried(name, "needs the sample times")
        q = data.U.shape[1]
        m = min(self.max_constraints or q - 1, q - 1)
        cand = ev.Candidate(name, "one constant A in the stretches where it holds, none elsewhere",
                            lambda k: ConstraintInStretches(block=BLOCK_S, n_constraints=max(k, 1)), m)
        item = ev.Tried(cand, folds)
        try:
            found = stretches_held_out(data, folds, m)
        except (LearningError, InputError, np.linalg.LinAlgError, FloatingPointError) as exc:
            item.k, item.note = None, f"failed: {getattr(exc, 'message', None) or exc}"
            return item
        item.rows, item.k, item.evidence, item.rank_reason = found.rows, found.k, found.evidence, found.reason
        item.errors, item.scored_on = found.errors, folds
        item.extra = {"time_share": found.share, "min_time_share": MIN_SHARE}
        return item

    def _choose(self, data: ev.Sample, tried: list[ev.Tried], skipped: list[dict[str, Any]],
                every: ev.Sample | None = None) -> None:
        """k*, the winner by the one-SE rule among the candidates of rank k*, its refit on all
        the data (``every``; None: ``data``, which the candidates were tried on), ``selection_``
        and ``heldout_`` (module docstring)."""
        ok = [c for c in tried if c.k is not None]
        if self.n_constraints is not None:
            k_star = int(self.n_constraints)
            top = [c for c in ok if c.rows.shape[1] >= k_star]
        else:
            k_star = max([c.k for c in ok], default=0)
            top = [c for c in ok if c.k == k_star]
        local = [c for c in top if c.candidate.segments is not None]
        common = local[-1].folds if local else None  # the finest stretches: blocks inside them
        for c in top:
            if c.candidate.name != "stretches":  # scored on its own folds by stretches.held_out
                ev.score(c, k_star, data, common)
        winner = best = None
        if k_star > 0 and top:
            best = min(top, key=lambda c: c.mean)
            winner = next(c for c in top if ev.within_one_se(c, best))
        none_why = ("no candidate's held-out motion is at the noise level along any row" if winner is None
                    else f"{k_star} constraint(s) hold on held-out data")
        rows = [{**ev.not_tried("none", ""), "model": "no constraint (Ñ = I)", "k": 0, "heldout_error": 0.0,
                 "se": 0.0, "chosen": winner is None, "reason": none_why}]
        rows += [c.row(c is winner, _why(c, winner, best, k_star, top)) for c in tried] + skipped
        self.model_ = self._refit(data if every is None else every, winner, k_star)
        self.n_constraints_ = int(k_star)
        label = winner.candidate.label if winner else "no constraint"
        reason = (NO_CONSTRAINT + " (held out, every candidate)" if winner is None else
                  f"{k_star} constraint(s) hold on held-out data; {label} is the simplest model of that rank "
                  "within one SE of the best held-out NPOE")
        if isinstance(self.model_, ConstraintInStretches):
            reason = (f"no constraint holds over the whole recording; {k_star} constraint(s) hold in "
                      f"stretches on held-out data ({winner.rank_reason}): {self.model_.summary()}")
        elif isinstance(self.model_, PerSegment):
            reason += f" ({self.model_.summary()})"
        self.heldout_ = None if winner is None else {
            "error": "NPOE", "mean": winner.mean, "se": winner.se, "per_fold": winner.errors.tolist(),
            "folds": winner.scored_on.reason}
        if isinstance(self.model_, PerWindow | ConstraintInStretches):
            self.model_.heldout_ = self.heldout_
        values = [] if winner is None else [float(v) for v in winner.evidence.ratio]
        self.selection_ = {"rule": "auto", "n_constraints": int(k_star), "model": label, "reason": reason,
                           "chosen": winner.candidate.name if winner else "none", "values": values,
                           "criterion": "held-out energy / noise variance of row k (the winner)",
                           "candidates": rows, **({"geometry": self.geometry_} if self.geometry_ else {})}
        final = None if winner is None else self.model_.constraint(data.X, groups=data.groups, t=data.t)
        self.selection_["sure"] = sure.summary(
            final, None if winner is None else winner.rows[:, :k_star], "" if winner is None else
            winner.folds.reason, self.selection_, data.U.shape[1], "no constraint")
        self.model_.selection_ = {**self.selection_, "winner_selection": self.model_.selection_}

    def _refit(self, data: ev.Sample, winner: ev.Tried | None, k: int) -> ConstraintModel:
        """The winner with k rows fitted on all the data (k = 0: :class:`NoConstraint`)."""
        if winner is None or k == 0:
            return NoConstraint().fit(data.X, data.U, groups=data.groups)
        how = data.derivative if winner.candidate.name == "stretches" else None  # its noise needs it
        return winner.candidate.make(k).fit(data.X, data.U, groups=data.groups, t=data.t, derivative=how)

    def _one_action(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None) -> None:
        """k = 0 at one action dimension (:data:`~.base.ONE_ACTION`): no candidate is tried."""
        self.model_ = NoConstraint().fit(X, U, groups=groups)
        self.n_constraints_ = 0
        self.heldout_ = None
        self.selection_ = {"rule": "auto", "n_constraints": 0, "model": "no constraint", "chosen": "none",
                           "reason": ONE_ACTION, "values": [], "criterion": "", "candidates": []}
        self.model_.selection_ = {**self.selection_, "winner_selection": self.model_.selection_}

    def _fit_without_cv(self, data: ev.Sample, why: str) -> None:
        """Too few samples to cross-validate: nhat, its rank by the noise rule on its own rows
        (nhat's own rule when that cannot judge)."""
        q = data.U.shape[1]
        rows = np.linalg.eigh(data.U.T @ data.U)[1].T[: q - 1]
        pieces = data.groups
        evidence = data.rows_evidence(np.broadcast_to(rows, (len(data.U), *rows.shape)), pieces)
        chosen = nr.noise_rank(evidence, min(self.max_constraints or q - 1, q - 1), share_rows=nr.SHARE_ROWS)
        k = self.n_constraints if self.n_constraints is not None else getattr(chosen, "n_constraints", None)
        model = NoConstraint() if k == 0 else StateIndependentConstraint(n_constraints=k, seed=self.seed)
        self.model_ = model.fit(data.X, data.U, groups=data.groups)
        self.n_constraints_ = int(self.model_.n_constraints_)
        self.heldout_ = None
        self.selection_ = {"rule": "auto", "n_constraints": self.n_constraints_, "model": "nhat" if
                           self.n_constraints_ else "no constraint", "chosen": "nhat" if self.n_constraints_
                           else "none", "reason": f"not cross-validated ({why}): "
                           + (chosen.reason if chosen is not None else self.model_.selection_["reason"]),
                           "values": [], "criterion": "", "candidates": []}


def _why(c: ev.Tried, winner: ev.Tried | None, best: ev.Tried | None, k_star: int,
         top: list[ev.Tried]) -> str:
    """Why a candidate won or lost, in words."""
    if c.k is None:
        return c.note
    if c not in top:
        return f"{c.k} constraint(s) on held-out data, fewer than {k_star}"
    if winner is None:
        return "no constraint"
    if c is winner:
        return (f"the best held-out NPOE of the models with {k_star} constraint(s)" if c is best else
                f"the simplest within one SE of the best held-out NPOE ({best.candidate.name}: "
                f"{best.mean:.3g} ± {best.se:.2g})")
    if top.index(c) < top.index(winner):
        return f"held-out NPOE {c.mean:.3g} ± {c.se:.2g}: more than one SE above the best"
    return f"{winner.candidate.name} is simpler and within one SE"
