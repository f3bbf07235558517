"""Scoring learnt models (ALGORITHMS.md §6) and using saved ones: the library side of the
pipeline's metrics and of ``ccl evaluate`` / ``ccl predict``.

Every number is an error of one model, named as in §6 (see docs/metrics.md), with its
normaliser computed from the data actually used and labelled by it (``normaliser_of``):

* constraint (learn-a): ``NPOE`` of the observations it was learnt from (u, or the learnt
  w̃ after a learn-v stage; minus the learnt task part Ã⁺b̃ when the model has one) and,
  with ground truth, ``NPPE``;
* null-space component (learn-v): ``NPE`` and, with ground truth, ``NUPE_w`` / ``NUPE_v``;
* policy (learn-pi): with ground truth ``NUPE`` and ``NCPE``; with a learnt constraint
  ``NCPE_obs`` (observations against Ñπ̃).

``convention="original"`` switches to the original library's normalisers (NPPE and NPOE:
var(π) for state-independent models, var of the true w for state-dependent ones; NPE:
ddof = 0).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli import metrics as M
from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError
from ccl_cli.learn.constraint import NoConstraint, PerDemonstration, PerWindow, StateIndependentConstraint
from ccl_cli.learn.constraint.base import projection_at
from ccl_cli.learn.constraint.windows import refit_on_new_demos

KINDS = {"learn-a": "constraint", "learn-v": "nullspace", "learn-pi": "policy"}


def _dict(*items: M.Metric) -> dict[str, dict]:
    return {m.name: m.as_dict() for m in items}


def _base(model: Any) -> Any:
    model = vars(model).get("model_", model)  # auto: the model it chose
    return model.estimator if isinstance(model, PerDemonstration) else model


def state_dependent(model: Any) -> bool:
    """Whether a constraint model's A depends on x (everything but nhat, per window or none)."""
    return not isinstance(_base(model), StateIndependentConstraint | PerWindow | NoConstraint)


def projection_on(model: Any, d: Demonstrations, Y: np.ndarray, new_data: bool = False
                  ) -> tuple[np.ndarray, str | None]:
    """Ñ (N, q, q) of a constraint model on ``d``, and None — or, for a model fitted per window
    or per demonstration on demonstrations it has not seen (any, with ``new_data``: a saved
    model on a recording), Ñ of the same kind of model fitted on ``d``'s observations ``Y``
    (N, q) and the sentence saying so."""
    refit = refit_on_new_demos(model, d.X, Y, d.demo, d.t, always=new_data)
    if refit is not None:
        return projection_at(refit[0], d.X, d.demo, d.t), refit[1]
    return projection_at(model, d.X, d.demo, d.t), None


def _has_true_constraint(d: Demonstrations) -> bool:
    return d.has_truth("pi") and (d.has_truth("N") or d.has_truth("A"))


def task_part(model: Any, X: np.ndarray, demo: np.ndarray | None = None) -> np.ndarray | None:
    """The learnt task part ṽ = Ã⁺ b̃ (§1) of a constraint model with a task term: (N, q),
    or ``None`` when the model has none (then ṽ = 0)."""
    if isinstance(model, PerDemonstration):
        if getattr(model.estimator, "task", False) is not True:
            return None
        demo = np.asarray(demo)
        out = np.zeros((len(X), next(iter(model.models_.values())).n_action_))
        for k in np.unique(demo):  # one small solve per demonstration, not per sample
            m = demo == k
            if int(k) not in model.models_:
                raise InputError(f"demonstration {int(k)} was not seen when fitting this model")
            out[m] = task_part(model.models_[int(k)], X[m])
        return out
    if getattr(model, "Wb_", None) is None:
        return None
    A = model.constraint(X)  # (N, s, q)
    b = model.task_term(X)  # (N, s)
    return np.einsum("nqs,ns->nq", np.linalg.pinv(A), b)


def constraint_metrics(model: Any, d: Demonstrations, Y: np.ndarray, convention: str = "ccl",
                       of: str = "u", new_data: bool = False) -> dict[str, dict]:
    """NPOE of the observations ``Y`` (N, q) the model was learnt from (``of`` names them)
    and, with ground truth π and N, NPPE; both under ``convention`` (``new_data``: see
    :func:`projection_on`)."""
    N_est, note = projection_on(model, d, Y, new_data)
    sd = state_dependent(model)
    truth = _has_true_constraint(d)
    Pi = d.truth["pi"] if truth else None
    W = None
    if truth and sd:
        W = d.truth["w"] if d.has_truth("w") else np.einsum("nij,nj->ni", d.true_projection(), Pi)
    items = [M.npoe(N_est, Y, convention, Pi=None if sd else Pi, W=W, V_est=task_part(model, d.X, d.demo),
                    of=of)]
    if truth:
        items.append(M.nppe(d.true_projection(), N_est, Pi, d.U, convention, state_dependent=sd))
    out = _dict(*items)
    if note:
        for entry in out.values():
            entry["note"] = note
    return out


def nullspace_metrics(w: np.ndarray, d: Demonstrations, convention: str = "ccl") -> dict[str, dict]:
    """NPE of the learnt w̃ (N, q) and, with ground truth, NUPE of w and of v = u − w̃."""
    items = [M.npe(d.U, w, convention)]
    if d.has_truth("w"):
        items.append(M.nupe(d.truth["w"], w, "NUPE_w", "w"))
    if d.has_truth("v"):
        items.append(M.nupe(d.truth["v"], d.U - w, "NUPE_v", "v"))
    return _dict(*items)


def policy_metrics(est: np.ndarray, d: Demonstrations, constraint: Any = None, Y: np.ndarray | None = None,
                   of: str = "u") -> dict[str, dict]:
    """With ground truth: NUPE and NCPE of π̃ (N, q). With a learnt ``constraint`` (and the
    observations ``Y`` it was learnt from): NCPE_obs, the observations against Ñπ̃."""
    items = []
    if d.has_truth("pi"):
        items.append(M.nupe(d.truth["pi"], est))
        if _has_true_constraint(d):
            items.append(M.ncpe(d.true_projection(), d.truth["pi"], est))
    if constraint is not None:
        Y = d.U if Y is None else Y
        items.append(M.ncpe_observed(projection_on(constraint, d, Y)[0], Y, est,
                                     task_part(constraint, d.X, d.demo), of))
    return _dict(*items)


def evaluate_model(model: Any, kind: str, data: Demonstrations, convention: str = "ccl") -> dict:
    """Metrics of a saved model on ``data`` (all samples): the ones its ground truth allows.

    The same functions score the pipeline's stages, so a model scored on the same data
    and observations gets the same numbers here. A policy on data without ground truth
    has no metric (an empty dict). A model per window or per demonstration is fitted on
    ``data`` (the same window and rows; the metrics then carry a note saying so)."""
    if kind == "constraint":
        return constraint_metrics(model, data, data.U, convention, new_data=True)
    if kind == "nullspace":
        return nullspace_metrics(model.predict(data.X), data, convention)
    return policy_metrics(model.predict(data.X), data)


def check_dimensions(model: Any, data: Demonstrations) -> None:
    """The data's state and action dimensions match the model's (else InputError)."""
    q = getattr(model, "n_action_", None)
    if q is None and isinstance(model, PerDemonstration):
        q = next(iter(model.models_.values())).n_action_
    if q is not None and data.n_action != q:
        raise InputError(f"the model expects {q}-dimensional actions, the data has {data.n_action}")
    basis = getattr(model, "basis_", None) or (getattr(next(iter(model.models_.values())), "basis_", None)
                                               if isinstance(model, PerDemonstration) else None)
    if basis is not None:
        p = basis.centres_.shape[1] if hasattr(basis, "centres_") else basis.n_state_
        if data.n_state != p:
            raise InputError(f"the model expects {p}-dimensional states, the data has {data.n_state}")


# -- using saved models ------------------------------------------------------------------
def evaluate_saved(model_path: Path, data: Demonstrations, convention: str = "ccl") -> dict[str, Any]:
    """``ccl evaluate``: score the model saved at ``model_path`` on ``data``. Returns the
    summary (``metrics``: name → Metric dict) with ``entry``, metrics.json's content."""
    from ccl_cli.models import load_model

    est, info = load_model(model_path)
    check_dimensions(est, data)
    metrics = evaluate_model(est, info["kind"], data, convention)
    entry = {"method": info["method"], "kind": info["kind"], "convention": convention, "all": metrics}
    note = next((m["note"] for m in metrics.values() if "note" in m), None)
    return {"status": "ok", "command": "evaluate", "model": str(model_path), "kind": info["kind"],
            "method": info["method"], "convention": convention, "metrics": metrics,
            "entry": {**entry, "note": note} if note else entry, **({"note": note} if note else {}),
            "samples": data.n_samples, "demos": data.n_demos, "inputs": data.metadata.get("files")}


def predict(model: Any, kind: str, data: Demonstrations, notes: list[str] | None = None
            ) -> dict[str, np.ndarray]:
    """Predictions of a model on ``data``: x, u, t, demo and N (N, q, q) and w = N u for a
    constraint; w and v = u − w for a null-space component; π for a policy. A model per window
    or per demonstration is fitted on ``data`` first (it describes only its own recording), and
    ``notes`` gets the sentence saying so (a saved model: always)."""
    outputs: dict[str, np.ndarray] = {"x": data.X, "u": data.U, "t": data.t, "demo": data.demo}
    if kind == "constraint":
        N, note = projection_on(model, data, data.U, new_data=True)
        if note and notes is not None:
            notes.append(note)
        outputs["N"] = N
        outputs["w"] = np.einsum("nij,nj->ni", N, data.U)
    elif kind == "nullspace":
        outputs["w"] = model.predict(data.X)
        outputs["v"] = data.U - outputs["w"]
    else:
        outputs["pi"] = model.predict(data.X)
    return outputs


def write_predictions(out: Path, outputs: dict[str, np.ndarray], model_path: Path, method: str,
                      force: bool = False) -> None:
    """Write predictions atomically as CSV (one column per component, a header row) or HDF5
    (one dataset per output, attrs format="ccl-predictions", model, method)."""
    from ccl_cli.io.atomic import atomic_path

    suffix = out.suffix.lower()
    if suffix not in (".csv", ".h5", ".hdf5"):
        raise InputError(f"{out}: output must end in .h5 or .csv")
    if suffix == ".csv":
        cols, names = [], []
        for key, arr in outputs.items():
            flat = arr.reshape(len(arr), -1)
            cols.append(flat)
            names += [key] if flat.shape[1] == 1 else [f"{key}_{j}" for j in range(flat.shape[1])]
        with atomic_path(out, force=force) as tmp:
            np.savetxt(tmp, np.hstack(cols), delimiter=",", header=",".join(names), comments="")
        return
    import h5py

    with atomic_path(out, force=force) as tmp, h5py.File(tmp, "w") as f:
        f.attrs["format"] = "ccl-predictions"
        f.attrs["model"] = str(model_path)
        f.attrs["method"] = method
        for key, arr in outputs.items():
            f.create_dataset(key, data=arr)


def predict_saved(model_path: Path, data: Demonstrations, out: Path, force: bool = False) -> dict[str, Any]:
    """``ccl predict``: predictions of the model saved at ``model_path`` written to ``out``."""
    from ccl_cli.models import load_model

    if out.suffix.lower() not in (".csv", ".h5", ".hdf5"):
        raise InputError(f"{out}: output must end in .h5 or .csv")
    est, info = load_model(model_path)
    check_dimensions(est, data)
    notes: list[str] = []
    outputs = predict(est, info["kind"], data, notes)
    write_predictions(out, outputs, model_path, info["method"], force)
    return {"status": "ok", "command": "predict", "out": str(out), "samples": data.n_samples,
            "outputs": sorted(outputs), **({"note": notes[0]} if notes else {})}
