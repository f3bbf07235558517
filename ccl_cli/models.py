"""Saving and loading learnt models: HDF5 data with a schema version, never pickle.

::

    /            attrs: format="ccl-model", schema_version, kind (constraint | nullspace |
                        policy), method, params (JSON), fitted (JSON: counts, selection, ...),
                        training (JSON: config, input hashes, versions), created
    /arrays/...  the learnt arrays (weights, constraint rows, eigenvalues, ...)
    /basis/      attrs: kind (rbf | linear), sigma2 / n_state; centres (K, p)
    /demos/<id>/ the same layout once per demonstration (per-demonstration models)

Loading checks the format, the schema version, the method and every array's shape,
and rebuilds the estimator so predictions are bit-identical to the saved one's.
"""

from __future__ import annotations

import inspect
import json
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.basis import basis_from_state
from ccl_cli.constraint import (
    KnownFeatureConstraint,
    LinearConstraint,
    PerDemonstration,
    StateDependentConstraint,
    StateIndependentConstraint,
)
from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io.atomic import atomic_path
from ccl_cli.io.hdf5 import check_header
from ccl_cli.nullspace import NullSpaceComponent
from ccl_cli.policy import PolicyLearner

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
    "ncl": ["n_action_", "cost_", "n_iter_"],
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
    import h5py

    method = method_of(model)
    path = Path(path)
    with atomic_path(path, force=force) as tmp, h5py.File(tmp, "w") as f:
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


def _read(group, method: str, where: str) -> Any:
    if method not in CLASSES:
        raise InputError(f"{where}: unknown model method {method!r}")
    cls = CLASSES[method][1]
    try:
        params = json.loads(group.attrs["params"])
        fitted = json.loads(group.attrs["fitted"])
    except (KeyError, json.JSONDecodeError, TypeError) as exc:
        raise InputError(f"{where}: model attributes are damaged ({exc})") from None
    try:
        model = cls(**params)
    except TypeError as exc:
        raise InputError(f"{where}: parameters do not fit {cls.__name__} ({exc})") from None
    for key, value in fitted.items():
        setattr(model, key, value)
    arrays = group.get("arrays")
    if arrays is None:
        raise InputError(f"{where}: no /arrays group")
    for name in ARRAYS[method]:
        setattr(model, name, arrays[name][()] if name in arrays else None)
    if method in ("alpha", "lambda"):
        n = int(fitted.get("n_constraints_", 0))
        try:
            model.weights_ = [arrays[f"weights_{i}"][()] for i in range(n)]
        except KeyError:
            raise InputError(f"{where}: expected {n} weight arrays") from None
    if "basis" in group:
        g = group["basis"]
        state = {"kind": g.attrs["kind"]}
        if state["kind"] == "rbf":
            state.update(sigma2=float(g.attrs["sigma2"]), centres=g["centres"][()])
        else:
            state["n_state"] = int(g.attrs["n_state"])
        model.basis_ = basis_from_state(state)
    if method == "lambda":
        from ccl_cli.constraint.lambda_ import make_features

        model.features_ = make_features(model.features)
    _check_shapes(model, method, where)
    return model


def _check_shapes(model: Any, method: str, where: str) -> None:
    q = int(getattr(model, "n_action_", 0))
    K = model.basis_.n_features if hasattr(model, "basis_") else None
    bad = None
    if method == "nhat" and (model.A_ is None or model.A_.ndim != 2 or model.A_.shape[1] != q):
        bad = "A_"
    elif method == "ncl" and model.W_.shape != (q, K):
        bad = "W_"
    elif method == "policy" and model.W_.shape[0] != K:
        bad = "W_"
    elif method in ("alpha", "lambda"):
        d = q if method == "alpha" else int(model.n_task_)
        if any(w.shape != (d - 1 - k, K) for k, w in enumerate(model.weights_)):
            bad = "weights"
    elif method == "linear" and (model.W_ is None or model.W_.ndim != 2):
        bad = "W_"
    if bad:
        raise InputError(f"{where}: array {bad} has the wrong shape for a {method} model")


def load_model(path: str | Path) -> tuple[Any, dict[str, Any]]:
    """(estimator, info) from a model file; foreign or damaged files are refused."""
    import h5py

    path = Path(path)
    where = str(path)
    if not path.is_file():
        raise InputError(f"{where}: no such model file")
    try:
        f = h5py.File(path, "r")
    except OSError:
        raise InputError(f"{where}: not a ccl model (not an HDF5 file)") from None
    with f:
        check_header(f.attrs, where, FORMAT, "schema_version", SCHEMA_VERSION, "ccl model")
        method = str(f.attrs.get("method", ""))
        try:
            training = json.loads(f.attrs.get("training", "{}"))
        except json.JSONDecodeError:
            training = {}
        info = {"kind": str(f.attrs.get("kind")), "method": method, "training": training}
        try:
            if method.startswith("per_demo:"):
                base = method.split(":", 1)[1]
                template = CLASSES[base][1](**json.loads(f.attrs["params"]))
                model = PerDemonstration(template)
                model.models_ = {int(k): _read(g, base, f"{where}:/demos/{k}") for k, g in f["demos"].items()}
                fitted = json.loads(f.attrs["fitted"])
                model.n_constraints_ = fitted["n_constraints_"]
                model.selection_ = fitted["selection_"]
            else:
                model = _read(f, method, where)
        except InputError:
            raise
        except Exception as exc:  # damaged datasets, missing keys
            raise InputError(f"{where}: damaged model file ({type(exc).__name__}: {exc})") from None
    return model, info
