"""One constraint model per demonstration (e.g. a constant constraint that changes from
one demonstration to the next, ALGORITHMS.md §3.5 with the varying-constraint tutorial)."""

from __future__ import annotations

from typing import Any, ClassVar

import numpy as np

from ccl_cli.dataset import HowMade, group_rows
from ccl_cli.errors import InputError
from ccl_cli.learn.base import clone
from ccl_cli.learn.constraint.base import Applied, ConstraintModel, NewDataRule, refit_note, unseen
from ccl_cli.learn.model_selection import inner_heldout


class PerDemonstration(ConstraintModel):
    """Fit a copy of ``estimator`` on each demonstration separately.

    ``fit(X, U, groups=...)`` takes the demonstration id of each sample; without
    ``groups`` the data are one demonstration. Each copy is fitted on its demonstration's X
    and U alone (not the times). Predicting needs the demonstration id of each sample (one of
    those seen in ``fit``), except when a single demonstration was fitted. A demonstration it
    has not seen has no model here: the stated rule (:attr:`new_data_rule`) fits the estimator
    anew on it, and nothing of this model carries over.

    A demonstration of fewer than :data:`MIN_SAMPLES` samples takes the estimator fitted on all
    the samples given (one model, shared by such demonstrations).

    ``heldout``: also measure the held-out NPOE (eq. 3.8) of such a model, which can only be
    tested on its own demonstrations: K = 5 folds of contiguous blocks held out inside every
    demonstration (:func:`~ccl_cli.learn.model_selection.inner_folds`; the training samples
    within the derivative window of a held-out block dropped), each fold's model fitted per
    demonstration on the rest.

    Attributes:
        models_: dict demo id → fitted estimator. n_constraints_: the most common count;
        selection_, n_features_in_; heldout_ ({error, mean, se, per_fold, folds}, or None when
        not measured or most demonstrations are too short for the blocks and their gaps).
    """

    local_to = "demonstration"
    #: A demonstration with fewer samples than this has no model of its own (no estimator fits
    #: one sample): it takes the estimator fitted on every sample given at once, shared by all
    #: such demonstrations (``selection_["pooled"]`` lists them).
    MIN_SAMPLES = 2
    _fitted_attributes: ClassVar[dict[str, str]] = {
        "n_features_in_": "value", "n_constraints_": "value", "selection_": "value", "heldout_": "value",
        "models_": "models"}

    def __init__(self, estimator: ConstraintModel, *, heldout: bool = True) -> None:
        self._store_params(locals())

    @property
    def varies_with_state(self) -> bool:  # type: ignore[override]
        """As the estimator's."""
        return self.estimator.varies_with_state

    @property
    def n_action_(self) -> int:
        """q, the action dimension of every demonstration's model."""
        if "models_" not in vars(self):
            raise AttributeError("n_action_")
        return next(iter(self.models_.values())).n_action_

    def fit(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
            t: np.ndarray | None = None, derivative: HowMade = None
            ) -> PerDemonstration:
        """One copy of the estimator per demonstration of ``groups`` (N,) on X (N, p), U (N, q);
        ``derivative`` says how U was made (:class:`~ccl_cli.dataset.Derivative`), for the guard
        gaps of the held-out blocks; the times ``t`` are not read."""
        X, U = self._prepare_fit(X, U)
        groups = np.zeros(len(U), int) if groups is None else np.asarray(groups)
        self.models_: dict[int, Any] = {}
        ids, rows = group_rows(groups)
        short = [int(d) for d, m in zip(ids, rows, strict=True) if len(m) < self.MIN_SAMPLES]
        pooled = clone(self.estimator).fit(X, U) if short else None
        for d, m in zip(ids, rows, strict=True):  # loop over demonstrations, not samples
            own = len(m) >= self.MIN_SAMPLES
            self.models_[int(d)] = clone(self.estimator).fit(X[m], U[m]) if own else pooled
        counts = [m.n_constraints_ for m in self.models_.values()]
        self.n_constraints_ = int(np.bincount(counts).argmax())
        rules = sorted({str((getattr(m, "selection_", None) or {}).get("rule"))
                        for m in self.models_.values()})
        self.selection_ = {"rule": "per-demonstration",
                           "n_constraints": self.n_constraints_,
                           "per_demo": {int(k): int(m.n_constraints_) for k, m in self.models_.items()},
                           "inner_rules": rules,
                           "reason": (f"fixed by the user at {self.n_constraints_} in every demonstration"
                                      if rules == ["fixed"] else "most common count over demonstrations "
                                      f"(each chosen by rule {', '.join(rules)})")}
        if short:
            self.selection_["pooled"] = short
            self.selection_["reason"] += (f"; {len(short)} demonstration(s) of fewer than {self.MIN_SAMPLES} "
                                          "samples take the model fitted on all the samples")
        self.heldout_ = self._held_out(X, U, groups, derivative) if self.heldout else None
        return self

    def _held_out(self, X: np.ndarray, U: np.ndarray, groups: np.ndarray, derivative: HowMade
                  ) -> dict | None:
        """NPOE of the blocks held out inside every demonstration, mean and standard error over
        the folds; None when most demonstrations are too short for them."""
        twin = PerDemonstration(self.estimator, heldout=False)

        def error_of(train: np.ndarray, test: np.ndarray) -> float:
            twin.fit(X[train], U[train], groups=groups[train])
            return twin.held_out_error(X[test], U[test], groups=groups[test])

        return inner_heldout(np.unique(groups, return_inverse=True)[1].ravel(), derivative, error_of,
                             "demonstration")

    # -- the protocol ------------------------------------------------------------------------
    @property
    def new_data_rule(self) -> NewDataRule:
        """Fitted per demonstration: nothing carries over to a demonstration it has not seen."""
        return NewDataRule("fitted per demonstration", (),
                           "one model per demonstration it was fitted on: a demonstration it has not seen "
                           "has none, and the estimator is fitted anew on it (its own rule chooses k) — "
                           "figures there are training figures of that new fit")

    def applies_to(self, X: np.ndarray, U: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None, new_recording: bool = True) -> Applied:
        """Itself when every demonstration of ``groups`` (N,) was fitted here (and the data are a
        part of those recordings), else the estimator fitted anew per demonstration of X (N, p),
        U (N, q) (:attr:`new_data_rule`), with the note saying so."""
        self._check_fitted("models_")
        rule = self.new_data_rule
        if not unseen(set(self.models_), groups, new_recording):
            return Applied(self, rule)
        refit = PerDemonstration(clone(self.estimator)).fit(X, U, groups=groups)
        return Applied(refit, rule, refit_note("one constraint per demonstration"))

    def implied_n_features(self) -> int | None:
        """p when every demonstration's model holds the same one."""
        found = {p for m in self.models_.values() if (p := getattr(m, "n_features_in_", None)) is not None}
        return found.pop() if len(found) == 1 else None

    def models_by_demonstration(self) -> dict[int, ConstraintModel]:
        self._check_fitted("models_")
        return dict(self.models_)

    def projection(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ñ(X) of each sample's own demonstration: (N, p), groups (N,) → (N, q, q)."""
        self._check_fitted("models_")
        q = self.n_action_
        out = np.empty((X.shape[0], q, q))
        for d, rows in self._demo_rows(X, groups):  # a loop over demonstrations
            out[rows] = self.models_[d].projection(X[rows])
        return out

    def _demo_rows(self, X: np.ndarray, groups: np.ndarray | None) -> list[tuple[int, np.ndarray]]:
        """(demonstration id, its samples' rows) for each demonstration of ``groups`` (N,); one
        demonstration when None and only one was fitted; InputError for one not seen in fit."""
        self._check_fitted("models_")
        X = self._check_states(X)
        if groups is None:
            if len(self.models_) > 1:
                raise InputError("a per-demonstration constraint model needs the demonstration ids")
            groups = np.full(len(X), next(iter(self.models_)))
        groups = np.asarray(groups)
        out = []
        for d, rows in zip(*group_rows(groups), strict=True):
            if int(d) not in self.models_:
                raise InputError(f"demonstration {int(d)} was not seen when fitting this model")
            out.append((int(d), rows))
        return out

    def task_part(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                  t: np.ndarray | None = None) -> np.ndarray | None:
        """ṽ = Ã⁺b̃ of each sample's own demonstration: (N, p), groups (N,) → (N, q); None when
        the estimator has no task term."""
        self._check_fitted("models_")
        first = next(iter(self.models_.values()))
        if first.task_part(X[:1]) is None:
            return None
        out = np.zeros((len(X), first.n_action_))
        for d, rows in self._demo_rows(X, groups):  # one small solve per demonstration
            out[rows] = self.models_[d].task_part(X[rows])
        return out

    def constraint(self, X: np.ndarray, *, groups: np.ndarray | None = None,
                   t: np.ndarray | None = None) -> np.ndarray:
        """Ã of each sample's own demonstration: (N, s, q), s the most rows any demonstration's
        model has; a model with fewer is padded with rows of zeros (which constrain nothing: Ñ
        is unchanged)."""
        demos = self._demo_rows(X, groups)
        out = np.zeros((len(X), max(m.n_constraints_ for m in self.models_.values()), self.n_action_))
        for d, rows in demos:  # a loop over demonstrations
            A = self.models_[d].constraint(X[rows])
            out[rows, : A.shape[1]] = A
        return out
