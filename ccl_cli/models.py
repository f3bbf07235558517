"""Saving and loading learnt models: HDF5 data with a schema version, never pickle.

::

    /            attrs: format="ccl-model", schema_version, kind (constraint | nullspace |
                        policy), method, params (JSON), fitted (JSON: counts, selection, ...),
                        training (JSON: config, input hashes, versions), created
    /arrays/...  the learnt arrays (weights, constraint rows, eigenvalues, ...)
    /basis/      attrs: kind (rbf | linear), sigma2 / n_state; centres (K, p)
    /demos/<id>/ the same layout once per demonstration (per-demonstration models)

Loading goes through :func:`ccl_cli.io.open_hdf5` (nothing outside the file is
ever read, damaged files cannot hang libhdf5) and checks the format, the schema version,
the method, the type of every attribute and parameter, and every array's type, shape
and finiteness; then it rebuilds the estimator so predictions are bit-identical to the
saved one's. Any problem is one :class:`~ccl_cli.errors.InputError` naming the file and
the object at fault.
"""

from __future__ import annotations

import inspect
import json
import math
import typing
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli import io as h5safe
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io import check_header
from ccl_cli.learn.basis import basis_from_state
from ccl_cli.learn.constraint import (
    KnownFeatureConstraint,
    LinearConstraint,
    PerDemonstration,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.policy import PolicyLearner

FORMAT = "ccl-model"
SCHEMA_VERSION = 1

CLASSES: dict[str, tuple[str, type]] = {
    "nhat": ("constraint", StateIndependentConstraint),
    "alpha": ("constraint", StateDependentConstraint),
    "lambda": ("constraint", KnownFeatureConstraint),
    "linear": ("constraint", LinearConstraint),
    "ncl": ("nullspace", NullSpaceComponent),
    "policy": ("policy", PolicyLearner),
}
#: fitted arrays and scalars per method (name → attribute)
ARRAYS = {
    "nhat": ["A_", "eigenvalues_", "residuals_"],
    "alpha": [],
    "lambda": [],
    "linear": ["W_", "Wb_", "singular_values_", "scale_"],
    "ncl": ["W_"],
    "policy": ["W_"],
}
SCALARS = {
    "nhat": ["n_constraints_", "n_action_", "selection_"],
    "alpha": ["n_constraints_", "n_action_", "selection_", "nmse_"],
    "lambda": ["n_constraints_", "n_action_", "n_task_", "selection_", "nmse_", "n_dropped_"],
    "linear": ["n_constraints_", "n_action_", "selection_"],
    "ncl": ["n_action_", "cost_", "n_iter_", "stop_reason_"],
    "policy": ["n_action_", "n_used_"],
}


def method_of(model: Any) -> str:
    for name, (_, cls) in CLASSES.items():
        if type(model) is cls:
            return name
    if isinstance(model, PerDemonstration):
        return "per_demo:" + method_of(model.estimator)
    raise ConfigError(f"cannot save a {type(model).__name__}")


def _params(model: Any) -> dict[str, Any]:
    params = {}
    for name in inspect.signature(type(model).__init__).parameters:
        if name == "self":
            continue
        value = getattr(model, name)
        if callable(value):
            raise ConfigError(f"{type(model).__name__}.{name} is a Python callable and cannot be saved; "
                              "use a built-in (an arm name, or regressors identity/rbf/polynomial)")
        if hasattr(value, "state"):  # a basis object given directly: saved from the fitted basis
            value = None
        params[name] = value
    return params


def _json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer | np.floating):
        return value.item()
    raise TypeError(type(value).__name__)


def _write(group, model: Any, method: str) -> None:
    group.attrs["method"] = method
    group.attrs["params"] = json.dumps(_params(model), default=_json)
    fitted = {k: getattr(model, k) for k in SCALARS[method] if hasattr(model, k)}
    group.attrs["fitted"] = json.dumps(fitted, default=_json)
    arrays = group.create_group("arrays")
    for name in ARRAYS[method]:
        value = getattr(model, name, None)
        if value is not None:
            arrays.create_dataset(name, data=np.asarray(value))
    for i, w in enumerate(getattr(model, "weights_", []) if method in ("alpha", "lambda") else []):
        arrays.create_dataset(f"weights_{i}", data=w)
    basis = getattr(model, "basis_", None)
    if basis is not None:
        g = group.create_group("basis")
        state = basis.state()
        g.attrs["kind"] = state["kind"]
        if state["kind"] == "rbf":
            g.attrs["sigma2"] = state["sigma2"]
            g.create_dataset("centres", data=state["centres"])
        else:
            g.attrs["n_state"] = state["n_state"]


def save_model(path: str | Path, model: Any, training: dict[str, Any] | None = None,
               force: bool = False) -> Path:
    """Write ``model`` to ``path`` atomically."""
    method = method_of(model)
    path = Path(path)
    with h5safe.create_hdf5(path, force=force) as f:
        f.attrs["format"] = FORMAT
        f.attrs["schema_version"] = SCHEMA_VERSION
        base = method.split(":")[-1]
        f.attrs["kind"] = CLASSES[base][0]
        f.attrs["training"] = json.dumps(training or {}, default=str)
        if isinstance(model, PerDemonstration):
            f.attrs["method"] = method
            f.attrs["fitted"] = json.dumps({"n_constraints_": model.n_constraints_,
                                            "selection_": model.selection_}, default=_json)
            f.attrs["params"] = json.dumps(_params(model.estimator), default=_json)
            demos = f.create_group("demos")
            for d, sub in model.models_.items():
                _write(demos.create_group(str(d)), sub, base)
        else:
            _write(f, model, method)
    return path


#: fitted scalars that predictions depend on: name → (lowest, highest) allowed integer
_COUNTS = {"n_action_": (1, 100_000), "n_constraints_": (0, 100_000), "n_task_": (1, 100_000)}
#: largest magnitude of a saved array: products of two such values stay finite
MAX_MAGNITUDE = 1e150
_JSON_TYPES = (str, int, float, bool, list, dict, type(None))


def _allowed_types(cls: type, name: str, default: Any) -> tuple[type, ...]:
    """The JSON types a constructor parameter may take, from its annotation (or default)."""
    try:
        hint = typing.get_type_hints(cls.__init__).get(name)
    except (NameError, TypeError):
        hint = None
    if hint is None:
        return _JSON_TYPES if default is None else (type(default),)
    args = typing.get_args(hint) or (hint,)
    out = tuple(a for a in (typing.get_origin(a) or a for a in args) if a in _JSON_TYPES)
    if float in out:
        out += (int,)
    if any(a is np.ndarray for a in args):
        out += (list,)
    return out or _JSON_TYPES


def _read_params(group, cls: type, where: str) -> dict[str, Any]:
    """The constructor parameters saved with a model, each checked against the
    constructor's signature (name and type)."""
    params = h5safe.attr_json(group.attrs, "params", where, kind=dict)
    sig = inspect.signature(cls.__init__).parameters
    for key, value in params.items():
        if key not in sig or key == "self":
            raise InputError(f"{where}: parameter {key!r} is not a parameter of {cls.__name__}")
        allowed = _allowed_types(cls, key, sig[key].default)
        ok = isinstance(value, allowed) and not (isinstance(value, bool) and bool not in allowed)
        if isinstance(value, float) and not math.isfinite(value):
            ok = False
        if not ok:
            names = ", ".join(sorted({t.__name__ for t in allowed}))
            raise InputError(f"{where}: parameter {key!r} must be {names}, got {value!r}"[:200])
    return params


def _fitted(group, where: str) -> dict[str, Any]:
    fitted = h5safe.attr_json(group.attrs, "fitted", where, kind=dict)
    for key, (lo, hi) in _COUNTS.items():
        if key in fitted:
            value = fitted[key]
            if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
                raise InputError(f"{where}: fitted {key} must be an integer in [{lo}, {hi}], got {value!r}"
                                 [:200])
    return fitted


def _read(group, method: str, where: str) -> Any:
    if method not in CLASSES:
        raise InputError(f"{where}: unknown model method {method!r}")
    cls = CLASSES[method][1]
    params = _read_params(group, cls, where)
    fitted = _fitted(group, where)
    model = cls(**params)
    for key, value in fitted.items():
        if not key.endswith("_") or key not in SCALARS[method]:
            raise InputError(f"{where}: unknown fitted value {key!r} for a {method} model")
        setattr(model, key, value)
    for key in ("n_action_", *(("n_constraints_",) if method in ("nhat", "alpha", "lambda", "linear")
                               else ()), *(("n_task_",) if method == "lambda" else ())):
        if key not in fitted:
            raise InputError(f"{where}: fitted {key} is missing")
    arrays = h5safe.group_of(group, "arrays", where)
    for name in ARRAYS[method]:
        setattr(model, name, h5safe.numeric(arrays, name, where, ndim=(1, 2, 3), limit=MAX_MAGNITUDE)
                if h5safe.has(arrays, name, where) else None)
    if method in ("alpha", "lambda"):
        n = model.n_constraints_
        missing = [i for i in range(n) if not h5safe.has(arrays, f"weights_{i}", where)]
        if missing:
            raise InputError(f"{where}: expected {n} weight arrays, weights_{missing[0]} is missing")
        model.weights_ = [h5safe.numeric(arrays, f"weights_{i}", where, ndim=(2,), limit=MAX_MAGNITUDE)
                          for i in range(n)]
    basis = h5safe.group_of(group, "basis", where, required=False)
    if basis is not None:
        bwhere = f"{where}: /basis"
        kind = h5safe.attr_str(basis.attrs, "kind", bwhere)
        if kind == "rbf":
            centres = h5safe.numeric(basis, "centres", where, ndim=(2,), limit=MAX_MAGNITUDE)
            if centres.shape[0] < 1 or centres.shape[1] < 1:
                raise InputError(f"{where}: /basis/centres is empty ({centres.shape})")
            state = {"kind": kind, "centres": centres,
                     "sigma2": h5safe.attr_float(basis.attrs, "sigma2", bwhere, positive=True)}
        elif kind == "linear":
            n_state = h5safe.attr_int(basis.attrs, "n_state", bwhere)
            if not 1 <= n_state <= 100_000:
                raise InputError(f"{bwhere}: n_state must be a positive integer, got {n_state}")
            state = {"kind": kind, "n_state": n_state}
        else:
            raise InputError(f"{bwhere}: unknown basis kind {kind!r} (rbf or linear)")
        model.basis_ = basis_from_state(state)
    if method == "lambda":
        _check_features(model, where)
    _check_shapes(model, method, where)
    return model


def _check_features(model: Any, where: str) -> None:
    from ccl_cli.learn.constraint.lambda_ import make_features
    from ccl_cli.learn.kinematics import ARMS

    spec = model.features
    spec = {"arm": spec} if isinstance(spec, str) else spec
    if not isinstance(spec, dict) or set(spec) - {"arm", "rows", "kind"} or spec.get("arm") not in ARMS:
        raise InputError(f"{where}: features must name a built-in arm ({', '.join(ARMS)}), "
                         f"got {spec!r}"[:200])
    arm = ARMS[spec["arm"]]()
    n_rows = arm.jacobian(np.zeros((1, arm.n_joints))).shape[1]
    rows = spec.get("rows")
    if rows is not None and (not isinstance(rows, list) or not rows or any(
            not isinstance(r, int) or isinstance(r, bool) or not 0 <= r < n_rows for r in rows)):
        raise InputError(f"{where}: features.rows must be a list of Jacobian rows in [0, {n_rows}), "
                         f"got {rows!r}"[:200])
    model.features_ = make_features({"arm": spec["arm"], "rows": rows})
    r = n_rows if rows is None else len(rows)
    if model.n_task_ != r or model.n_action_ != arm.n_joints:
        raise InputError(f"{where}: n_task_ {model.n_task_} / n_action_ {model.n_action_} do not fit "
                         f"{spec['arm']} with {r} rows")
    if not hasattr(model, "basis_") or _n_state(model.basis_) != arm.n_joints:
        raise InputError(f"{where}: the basis does not fit {spec['arm']} ({arm.n_joints} joints)")


def _n_state(basis: Any) -> int:
    return int(basis.centres_.shape[1]) if hasattr(basis, "centres_") else int(basis.n_state_)


def _linear_width(model: Any, kind: str, q: int | None) -> list[int]:
    """Possible column counts of f(x) for regressors ``kind`` (×q for Φ_A)."""
    K = model.basis_.n_features if hasattr(model, "basis_") else None
    if kind in ("identity", "constant"):
        return [1]
    if kind == "rbf":
        return [K] if K else []
    degree = model.degree
    if not isinstance(degree, int) or not 0 <= degree <= 64:
        return []
    return [math.comb(p + degree, degree) for p in range(1, 1025)]


def _check_shapes(model: Any, method: str, where: str) -> None:
    q = model.n_action_
    K = model.basis_.n_features if hasattr(model, "basis_") else None
    s = getattr(model, "n_constraints_", None)
    needs_basis = method in ("alpha", "lambda", "ncl", "policy") or (
        method == "linear" and "rbf" in (model.regressors, model.task_regressors if model.task else None))
    if needs_basis and K is None:
        raise InputError(f"{where}: a {method} model needs a /basis group")
    bad = None
    if method == "nhat" and (model.A_ is None or model.A_.shape != (s, q)):
        bad = "A_"
    elif method == "ncl" and (model.W_ is None or model.W_.shape != (q, K)):
        bad = "W_"
    elif method == "policy":
        want = (K, _n_state(model.basis_) + 1, q) if model.method == "lwpi" else (K, q)
        if model.W_ is None or model.W_.shape != want:
            bad = "W_"
    elif method in ("alpha", "lambda"):
        d = q if method == "alpha" else model.n_task_
        if s > d - 1 or any(w.shape != (d - 1 - k, K) for k, w in enumerate(model.weights_)):
            bad = "weights"
    elif method == "linear":
        if model.regressors not in ("identity", "polynomial", "rbf") or \
                model.task_regressors not in ("constant", "polynomial", "rbf"):
            raise InputError(f"{where}: unknown regressors {model.regressors!r} / {model.task_regressors!r}")
        widths = _linear_width(model, model.regressors, q)
        if model.W_ is None or model.W_.ndim != 2 or model.W_.shape[0] != s or \
                model.W_.shape[1] not in [w * q for w in widths]:
            bad = "W_"
        elif model.task and (model.Wb_ is None or model.Wb_.ndim != 2 or model.Wb_.shape[0] != s or
                             model.Wb_.shape[1] not in _linear_width(model, model.task_regressors, q)):
            bad = "Wb_"
        elif not model.task:
            model.Wb_ = None
    if bad:
        raise InputError(f"{where}: array {bad} has the wrong shape for a {method} model")
    if K is not None and hasattr(model.basis_, "centres_"):
        # the feature map must give finite features (σ² and centres are finite and σ² > 0)
        beta = model.basis_.transform(model.basis_.centres_[:1])
        if not np.isfinite(beta).all():
            raise InputError(f"{where}: the basis gives non-finite features")


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """(estimator, info) from a model file; foreign, damaged or unsafe files are refused."""
    path = Path(path)
    where = str(path)
    with h5safe.open_hdf5(path, "model file") as f:
        check_header(f.attrs, where, FORMAT, "schema_version", SCHEMA_VERSION, "ccl model")
        method = h5safe.attr_str(f.attrs, "method", where)
        kind = h5safe.attr_str(f.attrs, "kind", where)
        try:  # informative only
            training = h5safe.attr_json(f.attrs, "training", where, {}, dict)
        except InputError:
            training = {}
        base = method.split(":", 1)[1] if method.startswith("per_demo:") else method
        if base not in CLASSES:
            raise InputError(f"{where}: unknown model method {method!r}")
        if kind != CLASSES[base][0]:
            raise InputError(f"{where}: kind {kind!r} does not match method {method!r}")
        info = {"kind": kind, "method": method, "training": training}
        if method.startswith("per_demo:"):
            if CLASSES[base][0] != "constraint":
                raise InputError(f"{where}: only constraint models can be per-demonstration")
            template = CLASSES[base][1](**_read_params(f, CLASSES[base][1], where))
            model = PerDemonstration(template)
            demos = h5safe.group_of(f, "demos", where)
            models = {}
            for k in h5safe.members(demos, where):
                if not k.lstrip("-").isdigit() or len(k) > 18:
                    raise InputError(f"{where}: /demos/{k} is not a demonstration id")
                models[int(k)] = _read(h5safe.group_of(demos, k, where), base, f"{where}:/demos/{k}")
            if not models:
                raise InputError(f"{where}: /demos holds no models")
            if len({m.n_action_ for m in models.values()}) > 1:
                raise InputError(f"{where}: per-demonstration models disagree on the action dimension")
            model.models_ = models
            fitted = h5safe.attr_json(f.attrs, "fitted", where, kind=dict)
            count = fitted.get("n_constraints_")
            if not isinstance(count, int) or isinstance(count, bool) or count < 0:
                raise InputError(f"{where}: fitted n_constraints_ must be a non-negative integer, "
                                 f"got {count!r}"[:200])
            model.n_constraints_ = count
            model.selection_ = fitted.get("selection_")
        else:
            model = _read(f, method, where)
    return model, info
