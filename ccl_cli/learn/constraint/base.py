"""The protocol every learnt constraint keeps (ALGORITHMS.md §1, §3): what the app, the model
files and the renderers may ask a constraint model — and all they ask.

=====================================  =========================================================
``fit(X, U, *, groups, t, derivative)``  one signature for every model: X (N, p), U (N, q),
                                       demonstration ids and sample times (N,), how U was made
                                       (:class:`~ccl_cli.dataset.Derivative`); a model that does
                                       not read one of them ignores it (its docstring says so)
``n_constraints_``, ``n_action_``      k rows, q actions; ``selection_`` how k was chosen
``constraint(X, *, groups, t)``        Ã at each sample, (N, s, q): the rows at given states
                                       (and, for a model per stretch, demonstrations and times)
``projection(X, *, groups, t)``        Ñ = I − Ã⁺Ã at each sample, (N, q, q)
``task_part(X, *, groups, t)``         ṽ = Ã⁺b̃ (N, q), None without a task term
``score(X, U, *, groups, t)``          the split's likelihood gain, comparable across k (higher
                                       is better); ``held_out_error`` the NPOE (§6) it is tuned by
``holds(X, *, groups, t)``             where the model claims its rows, (N,) bool
``is_local`` / ``local_to``            whether one fitted piece speaks only for a stretch of the
                                       recording, and which: None (global), ``demonstration``,
                                       ``window``, ``segment`` or ``stretch``
``varies_with_state``                  Ã depends on the state x (the original library's
                                       normaliser of §6 follows it)
``chosen_``                            the fitted model that answers (learn-a's ``auto``: the one
                                       it chose; ``selection_["reason"]`` says why)
``constant_rows()``                    the rows (s, q) of one constant Ã, else None
``windows()``                          the windows / segments and their rows, else None
``models_by_demonstration()``          the separate model of each demonstration, else None
``new_data_rule``                      how it applies to a recording it has not seen, stated
                                       (:class:`NewDataRule`: words and data)
``applies_to(X, U, *, groups, t, new_recording)``  the model as it applies to given data by
                                       that rule (:class:`Applied`): deterministic, and a fit it
                                       needs is said in its ``note``, never silent
``check_shapes()``                     (every learner) its learnt arrays fit together
=====================================  =========================================================

No caller needs to know a model's class: ``auto`` answers every question as the model it chose.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import ClassVar

import numpy as np

from ccl_cli.errors import ConfigError
from ccl_cli.learn.base import Estimator
from ccl_cli.learn.consistency import npoe_error, split_likelihood
from ccl_cli.learn.linalg import nullspace_projection
from ccl_cli.learn.params import Interval, out_of_range


@dataclass(frozen=True)
class NewDataRule:
    """How a fitted constraint model applies to a recording it has not seen.

    ``rule``: ``as fitted`` (nothing is fitted: the learnt Ã at the new states), ``rows fitted per
    stretch`` (the same kind of model, its parameters and k fixed, fitted on the new data's own
    stretches), ``stretches classified`` (the learnt rows kept, where they hold found on the new
    data) or ``fitted per demonstration`` (the estimator fitted anew on each new demonstration);
    ``keeps``: what carries over from the fit (empty: nothing — figures on new data are then
    not figures of this model); ``words``: the rule in a sentence."""

    rule: str
    keeps: tuple[str, ...]
    words: str

    @property
    def carries_over(self) -> bool:
        """Whether anything learnt carries over to a recording the model has not seen."""
        return bool(self.keeps)

    def as_dict(self) -> dict[str, object]:
        return {"rule": self.rule, "keeps": list(self.keeps), "words": self.words}


@dataclass(frozen=True)
class Applied:
    """A constraint model as it applies to given data (:meth:`ConstraintModel.applies_to`): the
    fitted ``model`` whose rows those data take, the ``rule`` that made it, and ``note`` — the
    sentence saying what was fitted on those data (None: the model applies as fitted)."""

    model: ConstraintModel
    rule: NewDataRule
    note: str | None = None

    @property
    def refitted(self) -> bool:
        return self.note is not None


#: The rule of a model that is one Ã(x) for every sample.
AS_FITTED = NewDataRule("as fitted", ("rows",), "one Ã(x) for every sample: a new recording takes the "
                        "learnt rows at its own states; nothing is fitted on it")


def unseen(known: set[int], groups: np.ndarray | None, new_recording: bool) -> bool:
    """Whether data of demonstrations ``groups`` (N,) (None: one, id 0) hold one a model fitted on
    the demonstrations ``known`` has not seen: any, for a ``new_recording`` (its ids say nothing)."""
    ids = {0} if groups is None else {int(d) for d in np.unique(groups)}
    return new_recording or not ids <= known


def refit_note(what: str) -> str:
    """The sentence of a model per stretch fitted again on data it describes (``what``: its kind)."""
    return (f"a model per stretch, fitted again on these data ({what}): it describes only the "
            "recordings it was fitted on, so its errors here are training figures")


class ConstraintModel(Estimator):
    """A learnt constraint: the protocol of the module docstring. Subclasses implement ``fit``
    and :meth:`constraint` (and may give a cheaper :meth:`projection`); a model per stretch
    also its locality, :meth:`applies_to` and :attr:`new_data_rule`.

    Attributes (after ``fit``): ``n_constraints_``, ``n_action_``, ``selection_`` (dict with
    the rule, the residuals it looked at and why it chose ``n_constraints_``), ``n_features_in_``.
    """

    #: None for one Ã(x) over every sample; else what one fitted piece speaks for.
    local_to: ClassVar[str | None] = None
    #: Whether Ã depends on the state x.
    varies_with_state: ClassVar[bool] = True

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: object = None) -> ConstraintModel:
        raise NotImplementedError

    # -- what the model is ------------------------------------------------------------------
    @property
    def is_local(self) -> bool:
        """Whether one fitted piece speaks only for a stretch of the recording (``local_to``)."""
        return self.local_to is not None

    @property
    def chosen_(self) -> ConstraintModel:
        """The fitted model that answers: this one (``auto`` gives the one it chose)."""
        self._check_fitted("n_constraints_")
        return self

    @property
    def new_data_rule(self) -> NewDataRule:
        """How this model applies to a recording it has not seen (:class:`NewDataRule`)."""
        return AS_FITTED

    def applies_to(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None, new_recording: bool = True) -> Applied:
        """This model as it applies to states X (N, p) and observations U (N, q) of
        demonstrations ``groups`` at times ``t`` (N,): by :attr:`new_data_rule`. ``new_recording``
        False: the data are a part of the recordings the model was fitted on (a held-out part),
        so a demonstration id it has seen is that demonstration. A global model applies as
        fitted."""
        self._check_fitted("n_constraints_")
        return Applied(self, self.new_data_rule)

    def constant_rows(self) -> np.ndarray | None:
        """The rows (s, q) when Ã is one constant matrix wherever the model holds, else None."""
        return None

    def windows(self) -> Windows | None:
        """The fixed windows or segments the model holds one constant Ã per, else None."""
        return None

    def models_by_demonstration(self) -> dict[int, ConstraintModel] | None:
        """Demonstration id → its own model, for a model fitted separately per demonstration."""
        return None

    # -- what it predicts -------------------------------------------------------------------
    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã(X): (N, p) → (N, s, q)."""
        raise NotImplementedError

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ñ(X) = I − Ã⁺Ã: (N, p) → (N, q, q) (ALGORITHMS.md §1)."""
        self._check_fitted("n_constraints_")
        return nullspace_projection(self.constraint(X, groups=groups, t=t))

    def task_part(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray | None:
        """The learnt task part ṽ = Ã⁺b̃ (§1) at states X (N, p): (N, q); None for a model
        without a task term (then ṽ = 0)."""
        return None

    def holds(self, X: np.ndarray, *, groups: np.ndarray | None = None,
              t: np.ndarray | None = None) -> np.ndarray:
        """Whether the model claims its rows at each sample: (N,) bool (everywhere, but for a
        constraint that holds in stretches)."""
        return np.ones(len(self._check_states(X)), dtype=bool)

    def held_out_error(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                       t: np.ndarray | None = None) -> float:
        """NPOE of actions U (N, q) at states X (N, p) (§6): mean ‖z − Ñ(x)z‖² / Σ var(u),
        z = u − ṽ (the learnt task part, when the model has one); 0 when every action (less its
        task part) lies in the learnt null space — the error a model of a given k is tuned by.

        Scored as the model applies to these data (:meth:`applies_to`, a part of the recordings
        it was fitted on): a demonstration it has seen takes its fitted rows, one it has not the
        rows its stated rule gives — a global model's own; for a model per stretch, rows fitted
        on that demonstration with k fixed, so the figure there is a training figure (a held-out
        one needs blocks held out inside its stretches, as ``heldout_`` and learn-a's ``auto``
        measure it)."""
        model, Z = self._applied(X, U, groups, t)
        return npoe_error(model.projection(X, groups=groups, t=t), Z, U)

    def score(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
              t: np.ndarray | None = None) -> float:
        """How much better the learnt split explains the actions U (N, q) (less the learnt task
        part) than no constraint: :func:`~ccl_cli.learn.consistency.split_likelihood` — higher
        is better and comparable across k, so that a search over ``n_constraints``
        (scikit-learn's ``GridSearchCV``) finds the number of quiet rows: NPOE alone is 0 for
        k = 0 and always prefers fewer rows. Applied to the data as :meth:`held_out_error` is."""
        model, Z = self._applied(X, U, groups, t)
        return split_likelihood(model.projection(X, groups=groups, t=t), Z)

    def _applied(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray | None, t: np.ndarray | None
                 ) -> tuple[ConstraintModel, np.ndarray]:
        """The model as it applies to these data and the actions less its task part: (model, (N, q))."""
        model = self.applies_to(X, U, groups=groups, t=t, new_recording=False).model
        U = np.asarray(U, dtype=float)
        V = model.task_part(X, groups=groups, t=t)
        return model, U if V is None else U - V


@dataclass(frozen=True)
class Windows:
    """The windows (or segments) of a model with one constant Ã per window: ``per`` in words
    ("4-s window"), ``spans`` (S, 3) [demonstration id, start s, end s] and ``rows`` (S, s, q)."""

    per: str
    spans: np.ndarray
    rows: np.ndarray


class TimedConstraint(ConstraintModel):
    """A constraint whose orthonormal rows depend on each sample's demonstration and time (one
    constant A per window, or in the stretches where it holds): Ñ = I − ÃᵀÃ."""

    varies_with_state = False

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ñ = I − ÃᵀÃ of each sample (orthonormal rows, or rows of zeros): (N, q, q)."""
        A = self.constraint(X, groups=groups, t=t)
        return np.eye(self.n_action_) - np.einsum("nki,nkj->nij", A, A)


#: The answer of every constraint learner at one action dimension (q = 1): a row on one action
#: forbids all motion, and a constraint leaves motion free (k ≤ q − 1 = 0).
ONE_ACTION = ("one action dimension: a constraint row on it would forbid all motion (a constraint leaves "
              "motion free: k ≤ q − 1 = 0), so no constraint: Ñ = I")


def one_action_selection() -> dict:
    """``selection_`` of the answer at one action dimension (:data:`ONE_ACTION`, k = 0)."""
    return {"rule": "one action", "n_constraints": 0, "values": [], "criterion": "", "reason": ONE_ACTION}


class UntunedAtOneAction:
    """Placed before :class:`~ccl_cli.learn.model_selection.Tunable` in a tunable learner's bases:
    at one action dimension its rule answers no rows whatever the basis (:data:`ONE_ACTION`), so
    there is nothing to tune (``tuning_`` None)."""

    def _fit_tuned(self, X: np.ndarray, U: np.ndarray, **kwargs: object) -> bool:
        if U.shape[1] == 1 and self.n_constraints is None:
            self.tuning_ = None
            return False
        return super()._fit_tuned(X, U, **kwargs)


def check_rows_asked(q: int, n_constraints: int | None) -> None:
    """ConfigError unless a fixed ``n_constraints`` is 0 … q − 1 (at q = 1: none, :data:`ONE_ACTION`)."""
    if n_constraints is None or n_constraints <= q - 1:
        return
    if q == 1:
        raise ConfigError(f"n_constraints = {n_constraints} on one action dimension: a constraint row on it "
                          "would forbid all motion (k ≤ q − 1 = 0)")
    raise ConfigError(out_of_range("n_constraints", n_constraints, Interval(0, q - 1, type=int)))
