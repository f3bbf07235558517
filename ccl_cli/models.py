"""Saving and loading learnt models: HDF5 data with a schema version, never pickle.

::

    /            attrs: format="ccl-model", schema_version, kind (constraint | nullspace |
                        policy), method, params (JSON), fitted (JSON: n_features_in_,
                        counts, selection, ...), training (JSON: config, input hashes, versions)
    /arrays/...  the learnt arrays (weights, constraint rows, eigenvalues, ...)
    /basis/      attrs: kind (rbf | linear), sigma2 / n_state; centres (K, p)
    /demos/<id>/ the same layout once per demonstration (per-demonstration models)

What is saved is what each learner declares in ``_fitted_attributes`` (a JSON value, an
array, one array per constraint row, the basis, or one model per demonstration) of the model
that answers for it (its ``chosen_``: learn-a's ``auto`` is saved as the model it chose).
Schema version 2 records ``n_features_in_`` (the state dimension p); version-1 files
are still read, p then inferred from the basis (or a linear model's polynomial
regressors) and left unchecked when nothing implies it (nhat, identity regressors).

Loading goes through :func:`ccl_cli.io.open_hdf5` (nothing outside the file is
ever read, damaged files cannot hang libhdf5) and checks the format, the schema version,
the method, the type of every attribute and parameter, and every array's type, shape
and finiteness; then it rebuilds the estimator so predictions are bit-identical to the
saved one's — each learner checks that its own arrays fit together (``check_shapes``) and
says what state dimension they imply (``implied_n_features``). Any problem is one
:class:`~ccl_cli.errors.InputError` naming the file and the object at fault.
"""

from __future__ import annotations

import inspect
import json
import math
import typing
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io.h5 import access as h5
from ccl_cli.io.h5.probe import open_hdf5
from ccl_cli.io.h5.seal import create_hdf5
from ccl_cli.learn.basis import basis_from_state
from ccl_cli.learn.constraint import (
    ConstraintInStretches,
    ContactPhases,
    KnownFeatureConstraint,
    LinearConstraint,
    ManifoldConstraint,
    NoConstraint,
    PerDemonstration,
    PerSegment,
    PerWindow,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.learn.nullspace import NullSpaceComponent
from ccl_cli.learn.params import parameter_hints
from ccl_cli.learn.policy import PolicyLearner

FORMAT = "ccl-model"
SCHEMA_VERSION = 2
#: Versions this ccl reads (1: before n_features_in_ was recorded).
READABLE_VERSIONS = (1, 2)

CLASSES: dict[str, tuple[str, type]] = {
    "nhat": ("constraint", StateIndependentConstraint),
    "alpha": ("constraint", StateDependentConstraint),
    "lambda": ("constraint", KnownFeatureConstraint),
    "linear": ("constraint", LinearConstraint),
    "per_window": ("constraint", PerWindow),
    "per_segment": ("constraint", PerSegment),
    "stretches": ("constraint", ConstraintInStretches),
    "contact": ("constraint", ContactPhases),
    "manifold": ("constraint", ManifoldConstraint),
    "none": ("constraint", NoConstraint),
    "ncl": ("nullspace", NullSpaceComponent),
    "policy": ("policy", PolicyLearner),
}
#: The method name a model file gives each class.
NAMES = {cls: name for name, (_, cls) in CLASSES.items()}


def _per_demonstration(model: Any) -> bool:
    """Whether a model holds one model per demonstration (declared learnt ``models``)."""
    return "models" in type(model)._fitted_attributes.values()


def method_of(model: Any) -> str:
    """The method name ``model`` is saved under (``per_demo:`` and its estimator's for one model
    per demonstration)."""
    if type(model) in NAMES:
        return NAMES[type(model)]
    if _per_demonstration(model):
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
        if isinstance(value, dict) and "robot" in value:  # saved as the chain itself (URDF text)
            fitted = getattr(model, f"{name}_", None)
            value = fitted.spec() if fitted is not None else value
        params[name] = value
    return params


def _json(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer | np.floating):
        return value.item()
    raise TypeError(type(value).__name__)


def _write(group, model: Any, method: str) -> None:
    """``model``'s method, parameters and declared learnt attributes into ``group``."""
    declared = type(model)._fitted_attributes
    group.attrs["method"] = method
    template = model.estimator if _per_demonstration(model) else model
    group.attrs["params"] = json.dumps(_params(template), default=_json)
    group.attrs["fitted"] = json.dumps({k: getattr(model, k) for k, kind in declared.items()
                                        if kind == "value" and hasattr(model, k)}, default=_json)
    arrays = group.create_group("arrays") if "models" not in declared.values() else None
    for name, kind in declared.items():
        value = getattr(model, name, None)
        if value is None:
            continue
        if kind == "array":
            arrays.create_dataset(name, data=np.asarray(value))
        elif kind == "arrays":
            for i, w in enumerate(value):
                arrays.create_dataset(f"{name}{i}", data=w)
        elif kind == "basis":
            _write_basis(group.create_group("basis"), value.state())
        elif kind == "models":
            demos = group.create_group("demos")
            for d, sub in value.items():
                _write(demos.create_group(str(d)), sub, method.split(":")[-1])


def _write_basis(g, state: dict[str, Any]) -> None:
    g.attrs["kind"] = state["kind"]
    if state["kind"] == "rbf":
        g.attrs["sigma2"] = state["sigma2"]
        g.create_dataset("centres", data=state["centres"])
    else:
        g.attrs["n_state"] = state["n_state"]


def save_model(path: str | Path, model: Any, training: dict[str, Any] | None = None,
               force: bool = False) -> Path:
    """Write ``model`` to ``path`` atomically."""
    model = model.chosen_  # auto: the model it chose, its selection_ the candidates table
    method = method_of(model)
    path = Path(path)
    with create_hdf5(path, force=force) as f:
        f.attrs["format"] = FORMAT
        f.attrs["schema_version"] = SCHEMA_VERSION
        f.attrs["kind"] = CLASSES[method.split(":")[-1]][0]
        f.attrs["training"] = json.dumps(training or {}, default=str)
        _write(f, model, method)
    return path


#: fitted scalars that predictions depend on: name → (lowest, highest) allowed integer
_COUNTS = {"n_action_": (1, 100_000), "n_constraints_": (0, 100_000), "n_task_": (1, 100_000),
           "n_features_in_": (1, 100_000)}
#: counts a model may lack: p is inferred when absent (version-1 files) or unknown (nhat fitted without X)
_OPTIONAL = ("n_features_in_",)
#: largest magnitude of a saved array: products of two such values stay finite
MAX_MAGNITUDE = 1e150
_JSON_TYPES = (str, int, float, bool, list, dict, type(None))


def _allowed_types(cls: type, name: str, default: Any) -> tuple[type, ...]:
    """The JSON types a constructor parameter may take, from its annotation (or default)."""
    hint = parameter_hints(cls).get(name)
    if hint is None:
        return _JSON_TYPES if default is None else (type(default),)
    args = (hint,) if typing.get_origin(hint) is typing.Literal else typing.get_args(hint) or (hint,)
    out = tuple(a for arg in args for a in ((type(v) for v in typing.get_args(arg))
                                            if typing.get_origin(arg) is typing.Literal
                                            else (typing.get_origin(arg) or arg,))
                if a in _JSON_TYPES)
    if float in out:
        out += (int,)
    if any(a is np.ndarray for a in args):
        out += (list,)
    return out or _JSON_TYPES


def _read_params(group, cls: type, where: str) -> dict[str, Any]:
    """The constructor parameters saved with a model, each checked against the
    constructor's signature (name and type)."""
    params = h5.attr_json(group.attrs, "params", where, kind=dict)
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
    fitted = h5.attr_json(group.attrs, "fitted", where, kind=dict)
    for key, (lo, hi) in _COUNTS.items():
        if key in fitted:
            value = fitted[key]
            if not isinstance(value, int) or isinstance(value, bool) or not lo <= value <= hi:
                raise InputError(f"{where}: fitted {key} must be an integer in [{lo}, {hi}], got {value!r}"
                                 [:200])
    return fitted


def _read(group, method: str, where: str) -> Any:
    """The model saved in ``group`` by :func:`_write`, every part checked."""
    base = method.split(":", 1)[1] if method.startswith("per_demo:") else method
    if base not in CLASSES:
        raise InputError(f"{where}: unknown model method {method!r}")
    cls = CLASSES[base][1]
    model = cls(**_read_params(group, cls, where))
    try:
        model._validate_params()
    except ConfigError as exc:
        raise InputError(f"{where}: {exc.message}"[:300]) from None
    if base != method:
        if CLASSES[base][0] != "constraint":
            raise InputError(f"{where}: only constraint models can be per-demonstration")
        model = PerDemonstration(model)
    declared = type(model)._fitted_attributes
    fitted = _fitted(group, where)
    for key, value in fitted.items():
        if declared.get(key) != "value":
            raise InputError(f"{where}: unknown fitted value {key!r} for a {method} model")
        setattr(model, key, value)
    for key in _COUNTS:
        if declared.get(key) == "value" and key not in fitted and key not in _OPTIONAL:
            raise InputError(f"{where}: fitted {key} is missing")
    arrays = h5.group_of(group, "arrays", where) if "models" not in declared.values() else None
    for name, kind in declared.items():
        if kind == "array":
            setattr(model, name, h5.numeric(arrays, name, where, ndim=(1, 2, 3), limit=MAX_MAGNITUDE)
                    if h5.has(arrays, name, where) else None)
        elif kind == "arrays":  # one per constraint row
            n = model.n_constraints_
            missing = [i for i in range(n) if not h5.has(arrays, f"{name}{i}", where)]
            if missing:
                raise InputError(f"{where}: expected {n} weight arrays, {name}{missing[0]} is missing")
            setattr(model, name, [h5.numeric(arrays, f"{name}{i}", where, ndim=(2,), limit=MAX_MAGNITUDE)
                                  for i in range(n)])
        elif kind == "basis":
            _read_basis(model, group, where)
        elif kind == "models":
            model.models_ = _read_demos(group, base, where)
    if base == "lambda":
        _check_features(model, where)
    robot = getattr(model, "regressors", None)
    if isinstance(robot, dict) and robot.get("kind") == "robot":  # rebuilt from the stored URDF text
        model.regressors_ = _robot(robot, where, "regressors")
    try:
        model.check_shapes()
    except InputError as exc:
        raise InputError(f"{where}: {exc.message} ({method} model)"[:300]) from None
    _check_lengths(model, base, where)
    _check_n_features(model, where)
    return model


def _check_lengths(model: Any, method: str, where: str) -> None:
    """The vectors a model keeps beside its weights (eigenvalues, residuals, singular values,
    scales) are as long as its weights imply: one per action (nhat), one per regressor
    column (linear); a file edited to another length is refused, not carried along."""
    want: dict[str, int] = {}
    if method == "nhat" and isinstance(getattr(model, "n_action_", None), int):
        want = {"eigenvalues_": model.n_action_, "residuals_": model.n_action_}
    elif method == "linear" and getattr(model, "W_", None) is not None:
        d = model.W_.shape[1] + (model.Wb_.shape[1] if model.task and model.Wb_ is not None else 0)
        want = {"singular_values_": d, "scale_": d}
    for name, n in want.items():
        value = getattr(model, name, None)
        if value is not None and value.shape != (n,):
            raise InputError(f"{where}: array {name} has shape {value.shape}, expected ({n},) for a {method} "
                             "model")


def _read_basis(model: Any, group, where: str) -> None:
    basis = h5.group_of(group, "basis", where, required=False)
    if basis is None:
        return
    bwhere = f"{where}: /basis"
    kind = h5.attr_str(basis.attrs, "kind", bwhere)
    if kind == "rbf":
        centres = h5.numeric(basis, "centres", where, ndim=(2,), limit=MAX_MAGNITUDE)
        if centres.shape[0] < 1 or centres.shape[1] < 1:
            raise InputError(f"{where}: /basis/centres is empty ({centres.shape})")
        state = {"kind": kind, "centres": centres,
                 "sigma2": h5.attr_float(basis.attrs, "sigma2", bwhere, positive=True)}
    elif kind == "linear":
        n_state = h5.attr_int(basis.attrs, "n_state", bwhere)
        if not 1 <= n_state <= 100_000:
            raise InputError(f"{bwhere}: n_state must be a positive integer, got {n_state}")
        state = {"kind": kind, "n_state": n_state}
    else:
        raise InputError(f"{bwhere}: unknown basis kind {kind!r} (rbf or linear)")
    model.basis_ = basis_from_state(state)


def _read_demos(group, base: str, where: str) -> dict[int, Any]:
    """The per-demonstration models under /demos (demonstration id → model)."""
    demos = h5.group_of(group, "demos", where)
    models = {}
    for k in h5.members(demos, where):
        if not k.lstrip("-").isdigit() or len(k) > 18:
            raise InputError(f"{where}: /demos/{k} is not a demonstration id")
        models[int(k)] = _read(h5.group_of(demos, k, where), base, f"{where}:/demos/{k}")
    if not models:
        raise InputError(f"{where}: /demos holds no models")
    if len({m.n_action_ for m in models.values()}) > 1:
        raise InputError(f"{where}: per-demonstration models disagree on the action dimension")
    return models


def _check_n_features(model: Any, where: str) -> None:
    """n_features_in_ as saved (version 2), else inferred (version 1); it must agree with
    what the model holds."""
    implied = model.implied_n_features()
    saved = getattr(model, "n_features_in_", None)
    if saved is None:
        if implied is not None:
            model.n_features_in_ = implied
    elif implied is not None and saved != implied:
        raise InputError(f"{where}: n_features_in_ is {saved} but the model's basis or regressors take "
                         f"{implied} state dimensions")


def _check_features(model: Any, where: str) -> None:
    """A lambda model's features: a built-in arm, or a robot stored as URDF text; its task and
    action dimensions and its basis must fit them."""
    from ccl_cli.learn.constraint.lambda_ import make_features
    from ccl_cli.learn.kinematics import ARMS

    spec = model.features
    spec = {"arm": spec} if isinstance(spec, str) else spec
    if isinstance(spec, dict) and spec.get("kind") == "robot":
        features = _robot(spec, where, "features")
        n_joints, n_rows, name = features.n_joints, 6, "the stored robot"
        rows = spec.get("rows")
    else:
        if not isinstance(spec, dict) or set(spec) - {"arm", "rows", "kind"} or spec.get("arm") not in ARMS:
            raise InputError(f"{where}: features must name a built-in arm ({', '.join(ARMS)}) or hold a "
                             f"robot, got {spec!r}"[:200])
        arm = ARMS[spec["arm"]]()
        n_joints, n_rows, name = arm.n_joints, arm.jacobian(np.zeros((1, arm.n_joints))).shape[1], spec["arm"]
        rows = spec.get("rows")
        features = None
    if rows is not None and (not isinstance(rows, list) or not rows or any(
            not isinstance(r, int) or isinstance(r, bool) or not 0 <= r < n_rows for r in rows)):
        raise InputError(f"{where}: features.rows must be a list of Jacobian rows in [0, {n_rows}), "
                         f"got {rows!r}"[:200])
    model.features_ = features or make_features({"arm": spec["arm"], "rows": rows})
    r = n_rows if rows is None else len(rows)
    if model.n_task_ != r or model.n_action_ != n_joints:
        raise InputError(f"{where}: n_task_ {model.n_task_} / n_action_ {model.n_action_} do not fit "
                         f"{name} with {r} rows")
    if not hasattr(model, "basis_") or model.basis_.n_state != n_joints:
        raise InputError(f"{where}: the basis does not fit {name} ({n_joints} joints)")


def _robot(spec: dict[str, Any], where: str, key: str) -> Any:
    """The robot features a model stores (``{kind: robot, urdf, frame, rows}``), rebuilt from
    the URDF text (one InputError naming the file when it does not parse)."""
    from ccl_cli.errors import CCLError
    from ccl_cli.learn.robots import robot_features

    if not isinstance(spec.get("urdf"), str):
        raise InputError(f"{where}: {key} holds a robot without its URDF text")
    try:
        return robot_features({k: v for k, v in spec.items() if k in ("urdf", "frame", "base", "rows")})
    except CCLError as exc:
        raise InputError(f"{where}: {key}: {exc.message}"[:300]) from None


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """(estimator, info) from a model file; foreign, damaged or unsafe files are refused."""
    path = Path(path)
    where = str(path)
    with open_hdf5(path, "model file") as f:
        found = h5.attr_str(f.attrs, "format", where, None)
        if found != FORMAT:
            raise InputError(f"{where}: not a ccl model (format attribute {found!r})")
        version = h5.attr_int(f.attrs, "schema_version", where)
        if version not in READABLE_VERSIONS:
            raise InputError(f"{where}: ccl model version {version} is not supported (this ccl reads "
                             f"versions {', '.join(map(str, READABLE_VERSIONS))})")
        method = h5.attr_str(f.attrs, "method", where)
        kind = h5.attr_str(f.attrs, "kind", where)
        try:  # informative only
            training = h5.attr_json(f.attrs, "training", where, {}, dict)
        except InputError:
            training = {}
        base = method.split(":", 1)[1] if method.startswith("per_demo:") else method
        if base not in CLASSES:
            raise InputError(f"{where}: unknown model method {method!r}")
        if kind != CLASSES[base][0]:
            raise InputError(f"{where}: kind {kind!r} does not match method {method!r}")
        model = _read(f, method, where)
    return model, {"kind": kind, "method": method, "training": training, "schema_version": version}


def is_model_file(path: str | Path) -> bool:
    """Whether ``path`` is an HDF5 file whose ``format`` attribute says ccl model (a file
    that is not HDF5 is not, nor is a folder such as a ROS 2 bag). A FIFO, device or socket
    is refused (InputError), never opened to wait on."""
    from ccl_cli.io.limits import open_regular
    from ccl_cli.io.sniff import HDF5_MAGIC

    path = Path(path)
    if path.is_dir():  # a ROS 2 bag folder
        return False
    with open_regular(path) as f:
        head = f.read(1024)
    if HDF5_MAGIC not in head:  # at 0, or behind the 512-byte user block ccl writes
        return False
    with open_hdf5(path, "model file") as f:
        return h5.attr_str(f.attrs, "format", str(path), None) == FORMAT


def describe_model(path: str | Path) -> dict[str, Any]:
    """What a model file holds, for ``ccl inspect``: its method and kind, the number of
    constraints and why, the basis, the dimensions, and what it was trained on (stage, input
    files and their sha256, the config, package versions, its train/test figures)."""
    model, info = load_model(path)
    demos = model.models_ if _per_demonstration(model) else None
    inner = next(iter(demos.values())) if demos else model
    out: dict[str, Any] = {"path": str(path), "format": FORMAT, "schema_version": info["schema_version"],
                           "method": model.method if info["kind"] == "policy" else info["method"],
                           "kind": info["kind"],
                           "n_features_in": getattr(model, "n_features_in_", None),
                           "n_action": getattr(inner, "n_action_", None)}
    if demos:
        out["demonstrations"] = sorted(demos)
    if hasattr(model, "n_constraints_"):
        out["n_constraints"] = int(model.n_constraints_)
        selection = getattr(model, "selection_", None) or {}
        out["selection"] = {k: selection[k] for k in ("rule", "reason", "sure") if k in selection}
    basis = getattr(inner, "basis_", None)
    if basis is not None:
        state = basis.state()
        out["basis"] = {"kind": state["kind"], **({"n_centres": int(len(state["centres"])),
                                                   "sigma2": float(state["sigma2"])} if state["kind"] == "rbf"
                                                  else {})}
    training = info.get("training") or {}
    out["training"] = {k: training[k] for k in ("stage", "inputs", "metrics", "versions", "repairs")
                       if k in training}
    if "config" in training:
        out["training"]["config"] = training["config"]
    return out
