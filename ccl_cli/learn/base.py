"""The small base every learner shares (scikit-learn's estimator conventions).

* Constructor parameters are keyword-only, stored unchanged under their own names, and
  are the whole configuration of a learner: :meth:`Estimator.get_params` reads them from
  the signature of ``__init__``, :meth:`Estimator.set_params` writes them
  (``basis__n_centres`` reaches into a nested estimator), :func:`clone` builds a new,
  unfitted learner with the same parameters. What each parameter accepts is declared
  once, in its annotation (format: :mod:`ccl_cli.learn.params`), and checked at the start
  of ``fit``.
* ``fit(X, U, *, groups=None)`` returns ``self`` (``groups``: demonstration id per
  sample). Every constraint learner takes one signature (:mod:`ccl_cli.learn.constraint.base`):
  ``fit(X, U, *, groups=None, t=None, derivative=None)`` — ``t`` (N,) the sample times in
  seconds, ``derivative`` how U was made (:class:`~ccl_cli.dataset.Derivative`); a learner
  that does not read one of them ignores it. Learnt attributes end in ``_``;
  ``n_features_in_`` is the state dimension p seen in ``fit`` and every prediction checks it.
  The learnt attributes a saved model holds are declared once in ``_fitted_attributes``
  (read by :mod:`ccl_cli.models`).
* ``score(X, U, ...)`` is minus the learner's own held-out consistency error (higher is
  better), so scikit-learn's ``GridSearchCV`` and ``cross_validate`` work unchanged.
* Metadata routing: the keyword-only arguments of ``fit`` and ``score`` beside X and U —
  ``groups``, ``t`` (every learner takes them; one that does not read them says so),
  ``derivative``, a pi-coupled policy's ``projections`` — are per-sample data of the
  recording, so every learner *requests* them by default: with
  ``sklearn.set_config(enable_metadata_routing=True)``, ``GridSearchCV(...).fit(X, U,
  groups=..., t=...)`` and ``cross_validate(..., params={...})`` give each fold's fit and
  score its part. ``set_fit_request`` / ``set_score_request`` change a request (``False``: not
  passed, a string: an alias), as on scikit-learn's own estimators. scikit-learn is imported
  only by :meth:`Estimator.get_metadata_routing` and ``__sklearn_tags__``, which only
  scikit-learn calls.
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
import functools
import inspect
from typing import Any, ClassVar

import numpy as np

from ccl_cli.errors import ConfigError, InputError, LearningError
from ccl_cli.learn.params import declared, validate_params


class NotFittedError(LearningError):
    """A learner was asked for a prediction before ``fit``."""


class Requests(dict):
    """A learner's changed metadata requests: method → {metadata: request}. scikit-learn's
    ``clone`` copies it with the learner (it calls ``__sklearn_clone__``), as :func:`clone` does."""

    def __sklearn_clone__(self) -> Requests:
        return copy.deepcopy(self)


def as_real(A: Any, name: str) -> np.ndarray:
    """``A`` as a float array; InputError for what is not a real dense array (None, sparse
    matrices, complex numbers: scikit-learn's phrases, so its checks read them)."""
    if A is None:
        raise InputError(f"{name}: Expected array-like (array or non-string sequence), got None")
    if hasattr(A, "toarray") or hasattr(A, "tocsr"):  # scipy.sparse, without importing it
        raise InputError(f"{name}: sparse input is not supported; pass a dense array (.toarray())")
    A = np.asarray(A)
    if np.iscomplexobj(A):
        raise InputError(f"{name}: Complex data not supported")
    return A.astype(float, copy=False)


def check_xu(X: np.ndarray, U: np.ndarray, min_samples: int = 2) -> tuple[np.ndarray, np.ndarray]:
    """States X (N, p) and actions U (N, q) as finite float arrays with N ≥ ``min_samples``."""
    X, U = as_real(X, "X"), as_real(U, "U")
    if X.ndim != 2 or U.ndim != 2 or X.shape[0] != U.shape[0]:
        raise InputError(f"X and U must be (N, p) and (N, q) with the same N, got {X.shape}, {U.shape}")
    if X.shape[0] < min_samples:
        n = X.shape[0]
        raise InputError(f"need at least {min_samples} samples, got {n} sample{'' if n == 1 else 's'}")
    if not (np.isfinite(X).all() and np.isfinite(U).all()):
        raise InputError("X or U contains NaN or inf")
    return X, U


@functools.cache
def _init_parameters(cls: type) -> tuple[str, ...]:
    """The names of the constructor parameters of ``cls``, sorted (read once per class: a
    search clones its learner for every candidate and fold)."""
    init = cls.__init__
    if init is object.__init__:
        return ()
    params = inspect.signature(init).parameters.values()
    return tuple(sorted(p.name for p in params if p.name != "self"
                        and p.kind not in (p.VAR_POSITIONAL, p.VAR_KEYWORD)))


@functools.cache
def _keyword_only(cls: type, method: str) -> tuple[str, ...]:
    """The keyword-only parameters of ``cls.method`` (read once per class and method)."""
    params = inspect.signature(getattr(cls, method)).parameters.values()
    return tuple(p.name for p in params if p.kind is p.KEYWORD_ONLY)


class Estimator:
    """Base of every learner: parameters from the constructor signature."""

    #: learnt attribute → how a saved model holds it: "value" (JSON), "array", "arrays" (a
    #: list of arrays), "basis" (a fitted feature map), "models" (one model per demonstration).
    _fitted_attributes: ClassVar[dict[str, str]] = {}

    @classmethod
    def _param_names(cls) -> list[str]:
        return list(_init_parameters(cls))

    def _store_params(self, values: dict[str, Any]) -> None:
        """Store the constructor's arguments unchanged under their own names (call with
        ``locals()`` as the constructor's only statement)."""
        for name in self._param_names():
            setattr(self, name, values[name])

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

    def _validate_params(self) -> None:
        """Check every constructor parameter against its annotation
        (:func:`~ccl_cli.learn.params.declared`; :class:`~ccl_cli.errors.ConfigError` naming
        the class and the parameter)."""
        validate_params(type(self).__name__, declared(type(self)), self.get_params(deep=False))

    def _prepare_fit(self, X: np.ndarray | None, U: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
        """The start of every ``fit``: validate the parameters and the data (X (N, p), U
        (N, q), see :func:`check_xu`) and record ``n_features_in_`` = p. ``X`` None (a
        learner that does not read states) leaves ``n_features_in_`` unset: any p is then
        accepted when predicting."""
        self._validate_params()
        U = as_real(U, "U")
        if X is not None:
            X = as_real(X, "X")
            if X.ndim == 2 and X.shape[1] == 0:  # scikit-learn's phrase
                raise InputError(f"X has 0 feature(s) (shape={X.shape}) while a minimum of 1 is required: "
                                 "give the states, or X=None to a learner that does not read them")
        X, U = check_xu(np.zeros((U.shape[0] if U.ndim else 0, 0)) if X is None else X, U)
        self.__dict__.pop("n_features_in_", None)  # a refit forgets the previous p
        if X.shape[1]:
            self.n_features_in_ = int(X.shape[1])
        return X, U

    def _check_states(self, X: np.ndarray) -> np.ndarray:
        """X (N, p) as finite floats, with p = ``n_features_in_`` (else one InputError: a
        state with NaN or inf has no prediction, and none is made up)."""
        X = as_real(X, "X")
        p = getattr(self, "n_features_in_", None)
        if X.ndim != 2:
            shape = f"(N, {'p' if p is None else p})"
            raise InputError(f"the model expects states as an {shape} array, got an array of shape "
                             f"{X.shape}. Reshape your data: X.reshape(1, -1) for one state")
        if p is not None and X.shape[1] != p:
            raise InputError(f"the model expects p = {p} state dimensions, got {X.shape[1]}")
        if not np.isfinite(X).all():
            bad = np.flatnonzero(~np.isfinite(X).all(axis=1))
            raise InputError(f"X contains NaN or inf in {len(bad)} of {len(X)} states (first: row {bad[0]}); "
                             "a model predicts at finite states only")
        return X

    # -- what a loaded model is checked with (ccl_cli.models) ---------------------------------
    @property
    def chosen_(self) -> Estimator:
        """The fitted model that answers for this one: itself (a learner that chooses among
        models — learn-a's ``auto``, :class:`~ccl_cli.learn.model_selection.Tuned` — gives the
        one it chose; a model file holds that one)."""
        return self

    def check_shapes(self) -> None:
        """InputError (naming the learnt array) unless the learnt arrays fit together: what a
        model read from a file is checked with before it predicts. Each learner checks its
        own arrays and then calls this, which checks that a fitted RBF basis gives finite
        features."""
        basis = vars(self).get("basis_")
        if basis is not None and hasattr(basis, "centres_") and \
                not np.isfinite(basis.transform(basis.centres_[:1])).all():
            raise InputError("the basis gives non-finite features")

    def _shape_error(self, name: str) -> InputError:
        return InputError(f"array {name} has the wrong shape for a {type(self).__name__}")

    def _basis_width(self) -> int:
        """K, the features of the fitted basis (InputError when the model holds none)."""
        basis = vars(self).get("basis_")
        if basis is None:
            raise InputError(f"a {type(self).__name__} needs a basis (a /basis group)")
        return int(basis.n_features)

    def implied_n_features(self) -> int | None:
        """The state dimension p that what the model holds implies (its fitted basis), None when
        nothing does: a file that does not record ``n_features_in_`` is read with it."""
        basis = vars(self).get("basis_")
        return None if basis is None else basis.n_state

    def _check_fitted(self, *attrs: str) -> None:
        """Raise :class:`NotFittedError` unless every learnt attribute in ``attrs`` exists."""
        if not all(hasattr(self, a) for a in attrs):
            raise NotFittedError(f"this {type(self).__name__} is not fitted yet: call fit(X, U) first")

    def _adopt(self, fitted: Estimator) -> None:
        """Take over every learnt attribute (public, ending in ``_``) of ``fitted``."""
        for name, value in vars(fitted).items():
            if name.endswith("_") and not name.startswith("_"):
                setattr(self, name, value)

    # -- scikit-learn's metadata routing ------------------------------------------------------
    def _metadata(self, method: str) -> tuple[str, ...]:
        """The metadata ``method`` (``fit`` or ``score``) takes: its keyword-only parameters."""
        return _keyword_only(type(self), method)

    def _set_request(self, method: str, requests: dict[str, bool | str | None]) -> Estimator:
        known = self._metadata(method)
        for name in requests:
            if name not in known:
                raise ConfigError(f"{type(self).__name__}.{method} takes no {name!r} "
                                  f"(it takes: {', '.join(known)})")
        table = Requests(vars(self).get("_metadata_request", {}))
        table[method] = {**table.get(method, {}), **requests}
        self._metadata_request = table  # cloned with the learner (here and by scikit-learn)
        return self

    def set_fit_request(self, **requests: bool | str | None) -> Estimator:
        """Which metadata scikit-learn routes to ``fit`` (True by default; False, None or an
        alias): ``est.set_fit_request(t=False)``."""
        return self._set_request("fit", requests)

    def set_score_request(self, **requests: bool | str | None) -> Estimator:
        """Which metadata scikit-learn routes to ``score`` (as :meth:`set_fit_request`)."""
        return self._set_request("score", requests)

    def get_metadata_routing(self) -> Any:
        """scikit-learn's ``MetadataRequest`` of this learner: ``fit`` and ``score`` request their
        metadata (:meth:`_metadata`) unless :meth:`set_fit_request` / :meth:`set_score_request`
        said otherwise. Only scikit-learn calls it, so only then is scikit-learn imported."""
        from sklearn.utils.metadata_routing import MetadataRequest

        request = MetadataRequest(owner=type(self).__name__)
        chosen = vars(self).get("_metadata_request", {})
        for method in ("fit", "score"):
            for name in self._metadata(method):
                getattr(request, method).add_request(param=name, alias=chosen.get(method, {}).get(name, True))
        return request

    def __sklearn_tags__(self) -> Any:
        """The description scikit-learn's meta-estimators and checks read (GridSearchCV, clone,
        ``parametrize_with_checks``): a 2-D numeric input without NaN, a multi-output target,
        fitting required. scikit-learn's own ``Tags``: only scikit-learn calls this, so it is
        imported here and nowhere else in ccl (a test-only dependency)."""
        from sklearn.utils import InputTags, Tags, TargetTags

        return Tags(estimator_type=None, target_tags=TargetTags(required=True, two_d_labels=True,
                                                                 multi_output=True, single_output=False),
                    input_tags=InputTags(two_d_array=True, allow_nan=False), requires_fit=True)

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
    out = type(estimator)(**{k: clone(v) for k, v in params.items()})
    if "_metadata_request" in vars(estimator):  # its metadata requests go with it
        out._metadata_request = copy.deepcopy(estimator._metadata_request)
    return out
