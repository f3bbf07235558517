"""Using saved models: ``ccl evaluate`` (metrics of a model on data, and its figures),
``ccl predict`` (its predictions on new states) and ``ccl inspect MODEL`` — library
functions the command line calls; the numbers come from :mod:`ccl_cli.app.scoring`.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.app.scoring import (
    KINDS,
    applied_on,
    constraint_metrics,
    nullspace_metrics,
    policy_metrics,
    projection_on,
)
from ccl_cli.dataset import Demonstrations, Repair
from ccl_cli.errors import InputError


def evaluate_model(model: Any, kind: str, data: Demonstrations, convention: str = "ccl") -> dict:
    """Metrics of a saved model on ``data`` (all samples): the ones its ground truth allows.

    The same functions score the pipeline's stages, so a model scored on the same data
    and observations gets the same numbers here. A policy on data without ground truth
    has no metric (an empty dict)."""
    if kind == "constraint":  # as it applies to a new recording: a model per stretch says what it fits there
        return constraint_metrics(applied_on(model, data, data.U, new_data=True), data, data.U, convention)
    if kind == "nullspace":
        return nullspace_metrics(model.predict(data.X), data, convention)
    return policy_metrics(model.predict(data.X), data)


def check_dimensions(model: Any, data: Demonstrations) -> None:
    """The data's state and action dimensions match the model's (``n_action_``, and
    ``n_features_in_`` when it recorded one; else InputError)."""
    q = getattr(model, "n_action_", None)
    if q is not None and data.n_action != q:
        raise InputError(f"the model expects {q}-dimensional actions, the data has {data.n_action}")
    p = getattr(model, "n_features_in_", None)
    if p is not None and data.n_state != p:
        raise InputError(f"the model expects {p}-dimensional states, the data has {data.n_state}")


# -- using saved models ------------------------------------------------------------------
def evaluate_saved(model_path: Path, data: Demonstrations, convention: str = "ccl", figures: bool = False
                   ) -> dict[str, Any]:
    """``ccl evaluate``: score the model saved at ``model_path`` on ``data``. Returns the
    summary (``metrics``: name → Metric dict; ``rule``: how the model applies to a recording it
    has not seen, :func:`new_data_rule`) with ``entry``, metrics.json's content, and with
    ``figures`` the figures' data (``views``: the same figures a run draws for its stage)."""
    from ccl_cli.app.stages import StageResult
    from ccl_cli.app.views import describe_constraint, stage_views
    from ccl_cli.models import load_model

    est, info = load_model(model_path)
    check_dimensions(est, data)
    metrics = evaluate_model(est, info["kind"], data, convention)
    entry = {"method": info["method"], "kind": info["kind"], "convention": convention, "all": metrics}
    note = next((m["note"] for m in metrics.values() if "note" in m), None)
    if note:
        entry["note"] = note
    views = []
    if figures:
        stage = {v: k for k, v in KINDS.items()}[info["kind"]]
        result = StageResult(stage, info["method"], est, info={})
        if info["kind"] == "constraint":
            result.info = {"selection": est.selection_, "constraint": describe_constraint(est, data)}
        views = stage_views(result, data, "all", data, False)
    return {"status": "ok", "command": "evaluate", "model": str(model_path), "kind": info["kind"],
            "method": info["method"], "convention": convention, "metrics": metrics, "entry": entry,
            "rule": new_data_rule(est, info["kind"]),
            "samples": data.n_samples, "demos": data.n_demos, "inputs": data.metadata.get("files"),
            "views": views, **({"note": note} if note else {})}


#: How a saved null-space or policy model applies to a recording it has not seen.
FUNCTION_RULE = {"rule": "as fitted", "keeps": ["function"],
                 "words": "a function of the state: a new recording takes the learnt {what} at its own "
                          "states; nothing is fitted on it"}
#: What ``ccl predict`` writes for the samples as read (:func:`per_sample_read`).
FILL_RULE = ("one row per sample read: a sample the sensor-fault repair mirrored back or re-stamped is "
             "predicted at its repaired value; one it dropped is filled with the row of the nearest sample "
             "kept in its demonstration (the earlier on a tie: a held value, a state that was recorded); "
             "columns sample (its index as read), repair (kept / mirrored / restamped / filled) and fault "
             "(why)")


def new_data_rule(model: Any, kind: str) -> dict[str, Any]:
    """How ``model`` (of ``kind``) applies to a recording it has not seen, stated: the constraint
    protocol's :attr:`new_data_rule` (as fitted, rows fitted per stretch, stretches classified,
    fitted per demonstration), or a null-space / policy model's :data:`FUNCTION_RULE`."""
    if kind == "constraint":
        return model.new_data_rule.as_dict()
    what = "null-space component w̃(x)" if kind == "nullspace" else "policy π̃(x)"
    return {**FUNCTION_RULE, "words": FUNCTION_RULE["words"].format(what=what)}


def predict(model: Any, kind: str, data: Demonstrations, notes: list[str] | None = None
            ) -> dict[str, np.ndarray]:
    """Predictions of a model on ``data``: x, u, t, demo and N (N, q, q) and w = N u for a
    constraint; w and v = u − w for a null-space component; π for a policy. A model per window
    or per demonstration is applied by its rule for a recording it has not seen (fitted on
    ``data`` first: it describes only its own recording), and ``notes`` gets the sentence
    saying so."""
    outputs: dict[str, np.ndarray] = {"x": data.X, "u": data.U, "t": data.t, "demo": data.demo}
    if kind == "constraint":
        applied = applied_on(model, data, data.U, new_data=True)
        N, note = projection_on(applied, data), applied.note
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


def per_sample_read(outputs: dict[str, np.ndarray], data: Demonstrations
                    ) -> tuple[dict[str, np.ndarray], dict[str, Any]]:
    """``outputs`` (one row per row of ``data``) as one row per sample read (:data:`FILL_RULE`,
    the nearest row by :meth:`~ccl_cli.dataset.Repair.places`), with ``sample`` (M,) int, ``repair`` and
    ``fault`` (M,) str; and what was done: ``samples_read``, ``left_out`` (samples with no place
    in the data: outside the demonstrations the options keep, or another stream's span) and
    ``repaired`` (action → fault → samples). Without a repair record: the rows as they are."""
    rep = data.repair
    n = data.n_samples
    if rep is None:
        rep = Repair.untouched(n)
    a, b, w = rep.places(data.demo)
    k = np.flatnonzero(a >= 0)
    nearest = np.where(w[k] > 0.5, b[k], a[k])
    out: dict[str, np.ndarray] = {key: arr[nearest] for key, arr in outputs.items()}
    done = rep.actions()[k].astype(object)
    done[done == "dropped"] = "filled"
    out["sample"] = k.astype(np.int64)
    out["repair"] = done
    out["fault"] = rep.reasons()[k].astype(object)
    repaired: dict[str, dict[str, int]] = {}
    changed = done != "kept"
    for action, fault in zip(done[changed], out["fault"][changed], strict=True):  # the few repaired
        repaired.setdefault(str(action), {}).setdefault(str(fault), 0)
        repaired[str(action)][str(fault)] += 1
    return out, {"samples_read": len(rep.row), "left_out": int(len(rep.row) - len(k)), "repaired": repaired}


def output_names(key: str, width: int, data: Demonstrations | None) -> tuple[list[str], list[str]]:
    """Names and units of the ``width`` columns of prediction ``key``: the data's state names
    for x, its action names for u, w, v and π (``w.<name>``), N[i][j] for the projection,
    t in s; ``key_j`` without names."""
    states = (data.state_names, data.state_units) if data is not None else None
    actions = (data.action_names, data.action_units) if data is not None else None
    named = {"x": states, "u": actions, "w": actions, "v": actions, "pi": actions}.get(key)
    if width == 1:
        return [key], ["s" if key == "t" else ""]
    if named is not None and len(named[0]) == width:
        return [f"{key}.{n}" for n in named[0]], list(named[1])
    if key == "N" and data is not None and width == data.n_action ** 2:
        q = data.n_action
        return [f"N[{i}][{j}]" for i in range(q) for j in range(q)], [""] * width
    return [f"{key}_{j}" for j in range(width)], [""] * width


#: The CSV format of a prediction column by its dtype's kind (else floats in full: %.18e).
CSV_FORMATS = {"O": "%s", "U": "%s", "S": "%s", "i": "%d", "u": "%d", "b": "%d"}


def write_predictions(out: Path, outputs: dict[str, np.ndarray], model_path: Path, method: str,
                      force: bool = False, data: Demonstrations | None = None,
                      attrs: dict[str, str] | None = None) -> None:
    """Write predictions atomically as CSV (one column per component, a header row naming
    each by the data's names with its unit: ``w.joint_1.velocity [rad/s]``; integers as such,
    text columns as they are) or HDF5 (one dataset per output with ``names`` and ``units``
    attributes, text as UTF-8 strings; attrs format="ccl-predictions", model, method and
    ``attrs``)."""
    from ccl_cli.io.atomic import atomic_path

    suffix = out.suffix.lower()
    if suffix not in (".csv", ".h5", ".hdf5"):
        raise InputError(f"{out}: output must end in .h5 or .csv")
    if suffix == ".csv":
        cols, names, fmt = [], [], []
        for key, arr in outputs.items():
            flat = arr.reshape(len(arr), -1)
            cols.append(flat.astype(object) if flat.dtype.kind in "OUS" else flat)
            labels, units = output_names(key, flat.shape[1], data)
            names += [f"{n} [{u}]" if u else n for n, u in zip(labels, units, strict=True)]
            fmt += [CSV_FORMATS.get(flat.dtype.kind, "%.18e")] * flat.shape[1]
        table = np.hstack([c.astype(object) for c in cols]) if any(c.dtype == object for c in cols) \
            else np.hstack(cols)
        with atomic_path(out, force=force) as tmp:
            np.savetxt(tmp, table, fmt=fmt, delimiter=",", header=",".join(names), comments="")
        return
    import h5py

    from ccl_cli.io.h5.seal import create_hdf5

    with create_hdf5(out, force=force, sealed=False) as f:
        f.attrs["format"] = "ccl-predictions"
        f.attrs["model"] = str(model_path)
        f.attrs["method"] = method
        for key, value in (attrs or {}).items():
            f.attrs[key] = value
        for key, arr in outputs.items():
            text = arr.dtype.kind in "OUS"
            ds = f.create_dataset(key, data=arr.astype(str).astype(object) if text else arr,
                                  dtype=h5py.string_dtype() if text else None)
            labels, units = output_names(key, int(np.prod(arr.shape[1:], dtype=int)), data)
            ds.attrs["names"], ds.attrs["units"] = labels, units


def predict_saved(model_path: Path, data: Demonstrations, out: Path, force: bool = False) -> dict[str, Any]:
    """``ccl predict``: predictions of the model saved at ``model_path`` on ``data``, one row per
    sample read (:func:`per_sample_read`), written to ``out``; the summary states the model's
    rule for a recording it has not seen (``rule``), the fill rule and what was repaired."""
    from ccl_cli.models import load_model

    if out.suffix.lower() not in (".csv", ".h5", ".hdf5"):
        raise InputError(f"{out}: output must end in .h5 or .csv")
    est, info = load_model(model_path)
    check_dimensions(est, data)
    notes: list[str] = []
    outputs, read = per_sample_read(predict(est, info["kind"], data, notes), data)
    rule = new_data_rule(est, info["kind"])
    write_predictions(out, outputs, model_path, info["method"], force, data,
                      {"rule": json.dumps(rule), "fill_rule": FILL_RULE})
    return {"status": "ok", "command": "predict", "out": str(out), "samples": len(outputs["sample"]), **read,
            "outputs": sorted(outputs), "rule": rule, "fill_rule": FILL_RULE,
            **({"note": notes[0]} if notes else {})}


def inspect_file(path: Path, options: Any = None, gap: float | None = None, base: Path | None = None,
                 configured: bool = False) -> dict[str, Any]:
    """``ccl inspect``: what a model file holds (:func:`ccl_cli.models.describe_model`), or what
    a recording holds (:func:`ccl_cli.io.inspect_recording`). ``configured`` (a config was
    given): the recording is also read as learning reads it with ``options``, and
    ``as_configured`` says what learning would get (:func:`ccl_cli.io.summary.summary`:
    demonstrations, samples each, duration, names), how the config cuts it and what the
    sensor-fault repair did per demonstration (``repairs``), so that inspect and learn never
    disagree on the demonstrations."""
    from ccl_cli.io import inspect_recording, read_dataset
    from ccl_cli.io.summary import repairs, summary
    from ccl_cli.models import describe_model, is_model_file

    if is_model_file(path):
        return describe_model(path)
    info = inspect_recording(path, options, gap, base)
    if configured:
        data, _ = read_dataset(options, [path], base)
        info["as_configured"] = {**summary(data), "split": _split_words(options), "repairs": repairs(data)}
    return info


def inspect_files(paths: list[Path], options: Any = None, gap: float | None = None, base: Path | None = None,
                  configured: bool = False) -> list[dict[str, Any]]:
    """``ccl inspect`` of several paths, globs or folders (:func:`~ccl_cli.io.files.expand_files`):
    :func:`inspect_file` of each, in order; a file given twice is refused as learning refuses it."""
    from ccl_cli.io.files import expand_files, given_once

    found = expand_files([str(p) for p in paths], digests=False)
    given_once(found)
    return [inspect_file(p, options, gap, base, configured) for p in found]


def _split_words(options: Any) -> str:
    """How the config's ``data.demos`` cuts a recording, in words."""
    demos = options.demos
    said = [f"{k}: {v}" for k, v in demos.model_dump(exclude_defaults=True).items()]
    return "data.demos: {" + ", ".join(said) + "}" if said else "no data.demos option: one per file/run"
