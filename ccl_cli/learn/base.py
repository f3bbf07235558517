"""The small base every learner shares (scikit-learn's estimator conventions).

* Constructor parameters are keyword-only, stored unchanged under their own names,
  and are the whole configuration of a learner: :meth:`Estimator.get_params` reads
  them from the signature of ``__init__``, :meth:`Estimator.set_params` writes them
  (``basis__n_centres`` reaches into a nested estimator), :func:`clone` builds a new,
  unfitted learner with the same parameters.
* ``fit`` returns ``self``; learnt attributes end in ``_``; ``n_features_in_`` is the
  state dimension p seen in ``fit``.
* Asking a learner for a prediction before ``fit`` raises :class:`NotFittedError`.

:class:`NotFittedError` is a :class:`~ccl_cli.errors.LearningError` (exit code 1): a
learner asked for a result it has not learnt "could not produce a result", which is
what LearningError means. It is not bad *input*: the data given to ``predict`` may be
perfectly valid, and in the command line every model comes from ``fit`` or from
``load_model`` (which checks the file), so the error only reaches a library user who
skipped ``fit``.
"""

from __future__ import annotations

import copy
import inspect
from typing import Any

import numpy as np

from ccl_cli.errors import InputError, LearningError


class NotFittedError(LearningError):
    """A learner was asked for a prediction before ``fit``."""


class Estimator:
    """Base of every learner: parameters from the constructor signature."""

    @classmethod
    def _param_names(cls) -> list[str]:
        init = cls.__init__
        if init is object.__init__:
            return []
        params = inspect.signature(init).parameters.values()
        return sorted(p.name for p in params if p.name != "self"
                      and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD))

    def get_params(self, deep: bool = True) -> dict[str, Any]:
        """Constructor parameters → values; with ``deep``, also ``name__sub`` entries of
        nested estimators (and of objects with ``get_params``, e.g. a basis)."""
        out: dict[str, Any] = {}
        for name in self._param_names():
            value = getattr(self, name)
            out[name] = value
            if deep and hasattr(value, "get_params") and not isinstance(value, type):
                out.update({f"{name}__{k}": v for k, v in value.get_params(deep=True).items()})
        return out

    def set_params(self, **params: Any) -> Estimator:
        """Set constructor parameters (``name__sub`` sets ``sub`` of the nested object)."""
        valid = self._param_names()
        nested: dict[str, dict[str, Any]] = {}
        for key, value in params.items():
            name, _, sub = key.partition("__")
            if name not in valid:
                raise ValueError(f"{type(self).__name__} has no parameter {name!r} "
                                 f"(parameters: {', '.join(valid)})")
            if sub:
                nested.setdefault(name, {})[sub] = value
            else:
                setattr(self, name, value)
        for name, sub_params in nested.items():
            getattr(self, name).set_params(**sub_params)
        return self

    def _check_fitted(self, *attrs: str) -> None:
        """Raise :class:`NotFittedError` unless every learnt attribute in ``attrs`` exists."""
        if not all(hasattr(self, a) for a in attrs):
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet: call fit(X, U) first")

    # -- hyperparameter tuning (ccl_cli.learn.model_selection.tune) ----------------------------------
    #: Folds of this learner's default hyperparameter search (None: selection.TUNE_FOLDS).
    TUNE_FOLDS: int | None = None

    def _tune_grid(self, X: np.ndarray, U: np.ndarray) -> dict[str, list[Any]]:
        """The grid searched when ``tune`` is on: parameter → candidates (the current
        default first). Learners with hyperparameters override this."""
        return {}

    def _fit_tuned(self, X: np.ndarray, U: np.ndarray, **fit_kw: Any) -> bool:
        """When the learner's ``tune`` parameter is on (True, or a dict ``{budget: s,
        grid: {...}, folds: k, max_rows: m}``), choose its hyperparameters by
        cross-validation (:func:`ccl_cli.learn.model_selection.tune`) — on a seeded subset of about
        ``max_rows`` samples (:func:`ccl_cli.learn.model_selection.tuning_subset`) when there are more —
        fit the winner on all of X, U and take over its learnt attributes; ``tuning_``
        records the grid, the CV curve, the choice and any subset.
        The constructor parameters themselves are left unchanged. Returns False (and sets
        ``tuning_ = None``) when there is nothing to tune: the caller then fits as usual.
        """
        from ccl_cli.learn import model_selection as S

        spec = getattr(self, "tune", False)
        opts = spec if isinstance(spec, dict) else {}
        grid = (opts.get("grid") or self._tune_grid(np.asarray(X, dtype=float), np.asarray(U, dtype=float))
                ) if spec else {}
        self.tuning_ = None
        if not grid:
            return False
        base = clone(self).set_params(tune=False)
        groups, projections = fit_kw.get("demo"), fit_kw.get("projections")
        Xs, Us = X, U
        seed = int(getattr(self, "seed", 0))
        subset = S.tuning_subset(groups, len(U), seed, opts.get("max_rows"))
        if subset is not None:  # large N: search on a seeded subset, fit the winner on all
            rows, groups, subset_note = subset
            Xs, Us = np.asarray(X)[rows], np.asarray(U)[rows]
            projections = None if projections is None else np.asarray(projections)[rows]
        folds = int(opts.get("folds", self.TUNE_FOLDS or S.TUNE_FOLDS))
        try:
            S.make_folds(groups, len(Us), folds, 0, S.DEFAULT_GAP)
        except InputError as exc:  # too little data to cross-validate: say so, fit as given
            self.tuning_ = {"chosen": None, "reason": f"not tuned: {exc.message}"}
            return False
        from ccl_cli.learn import blas

        with blas.threads(blas.stage_threads(len(Us))):  # many small fits: one BLAS thread
            chosen, info = S.tune(base, Xs, Us, groups, grid,
                                  budget=float(opts.get("budget", S.TUNE_BUDGET)),
                                  n_folds=folds, seed=seed, projections=projections)
        if subset is not None:
            info["subset"] = subset_note
        best = base.set_params(**chosen).fit(X, U, **fit_kw)
        for name, value in vars(best).items():
            if name.endswith("_") and not name.startswith("_"):
                setattr(self, name, value)
        self.tuning_ = info
        return True

    def _set_n_features(self, X: np.ndarray) -> None:
        self.n_features_in_ = int(np.shape(X)[1])

    def __repr__(self) -> str:
        defaults = {p.name: p.default for p in inspect.signature(type(self).__init__).parameters.values()}
        changed = []
        for name in self._param_names():
            value = getattr(self, name, None)
            default = defaults.get(name, inspect.Parameter.empty)
            try:
                same = bool(value == default) if not isinstance(value, np.ndarray) else False
            except (TypeError, ValueError):
                same = False
            if not same:
                changed.append(f"{name}={value!r}")
        return f"{type(self).__name__}({', '.join(changed)})"


def clone(estimator: Any) -> Any:
    """A new, unfitted learner with deep copies of ``estimator``'s parameters (nested
    estimators are cloned too). Objects without ``get_params`` are deep-copied."""
    if isinstance(estimator, list | tuple):
        return type(estimator)(clone(e) for e in estimator)
    if not hasattr(estimator, "get_params") or isinstance(estimator, type):
        return copy.deepcopy(estimator)
    params = estimator.get_params(deep=False)
    return type(estimator)(**{k: clone(v) for k, v in params.items()})
