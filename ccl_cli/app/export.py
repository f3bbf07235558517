"""``ccl export``: a saved model as a documented, versioned, language-neutral file (YAML or JSON,
chosen by the suffix; the format field by field and a reference evaluator in plain numpy:
docs/export.md).

The model is read through :func:`ccl_cli.models.load_model` (every check of a model file) and
written as what its evaluation needs: a constraint's k and its rows, or the parameters of A(x)
and the formula they enter — per window, segment, phase or demonstration for a model per
stretch, with its rule for a recording it has not seen (``new_data_rule``) and what that rule
fits there; a null-space component's or a policy's basis and weights. With them: the names,
units and frame of the training data's columns, the training's provenance (inputs' sha256,
config, versions) and :data:`SCHEMA_VERSION`.
"""

from __future__ import annotations

import json
import math
import re
from itertools import combinations_with_replacement
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import InputError

FORMAT = "ccl-model-export"
#: Version of the exported layout (docs/export.md); a reader refuses versions it does not know.
SCHEMA_VERSION = 1
#: Output suffix → format written.
SUFFIXES = {".yaml": "yaml", ".yml": "yaml", ".json": "json"}
#: How N(x) follows from A(x) (``projection``): I − AᵀA (rows orthonormal, or zero), I − A⁺A.
ORTHONORMAL, PSEUDO_INVERSE = "orthonormal", "pseudo_inverse"

RBF = ("β_k(x) = exp(−‖x − c_k‖²/(2σ²)) / Σ_j exp(−‖x − c_j‖²/(2σ²)), K centres c_k; ‖x − c‖² computed "
       "as ‖x‖² − 2xᵀc + ‖c‖² (clipped at 0)")
ANGLES = ("rows one at a time: Q = I (d × d); for row j = 0 … k − 1: θ = W_j β(x) (d − 1 − j angles), "
          "a = a(θ) ∈ R^(d−j) the unit vector of hyperspherical angles (a_1 = cos θ_1, a_i = cos θ_i "
          "Π_{l<i} sin θ_l, a_(d−j) = Π_l sin θ_l), row_j = aᵀ Q[j:, :], then Q[j:, :] ← R(θ)ᵀ Q[j:, :], "
          "R(θ) = G_m ⋯ G_1, G_i the rotation by θ_i of the plane (i, i + 1)")
MANIFOLD_FEATURES = {
    "linear": "φ(z) = z",
    "sphere": "φ(z) = [z; ‖z‖²]",
    "quadric": "φ(z) = [z; z_a z_b for a ≤ b in row-major order: (1,1), (1,2), …, (1,q), (2,2), …, (q,q)]",
}
BLOCK_LOOKUP = ("a sample of demonstration d at time t (s) is in block j = ⌊t / block⌋ and takes the {what} "
                "of d whose blocks [first, end) hold j, else d's nearest {what} counted in blocks (the later "
                "one on a tie)")
DH = ("standard Denavit–Hartenberg: T_i = T_(i−1) Rz(x_i) Tz(d_i) Tx(a_i) Rx(α_i), T_0 = I; column i of the "
      "geometric Jacobian is [z_(i−1) × (o_n − o_(i−1)); z_(i−1)] (rows v_x, v_y, v_z, ω_x, ω_y, ω_z); "
      "Φ(x) = its rows `rows`")


def export_model(model_path: Path, out: Path, force: bool = False) -> dict[str, Any]:
    """Write the model saved at ``model_path`` to ``out`` (.yaml/.yml or .json) atomically; an
    existing ``out`` is replaced only with ``force``. Returns the summary ``--json`` prints."""
    from ccl_cli.io.atomic import atomic_path, check_writable
    from ccl_cli.io.files import file_hash
    from ccl_cli.models import load_model

    model_path, out = Path(model_path), Path(out)
    style = SUFFIXES.get(out.suffix.lower())
    if style is None:
        raise InputError(f"{out}: the export must end in .yaml, .yml or .json (it chooses the format)")
    if out.resolve() == model_path.resolve():
        raise InputError(f"{out}: the export would replace the model it is made from; choose another name")
    check_writable(out, force)  # before any work
    model, info = load_model(model_path)
    doc = document(model, info, {"file": str(model_path), "sha256": file_hash(model_path)})
    text = dump(doc, style)
    with atomic_path(out, force=force) as tmp:
        tmp.write_text(text, encoding="utf-8")
    summary = {"status": "ok", "command": "export", "model": str(model_path), "out": str(out),
               "format": style, "schema_version": SCHEMA_VERSION, "kind": doc["kind"],
               "method": doc["method"]}
    if doc["kind"] == "constraint":
        summary.update(k=doc["k"], scope=doc["scope"], form=doc["constraint"]["form"],
                       new_data=doc["new_data"]["rule"], reproducible=doc["new_data"]["reproducible"])
    return summary


# -- the document ------------------------------------------------------------------------------
def document(model: Any, info: dict[str, Any], source: dict[str, Any]) -> dict[str, Any]:
    """The exported document of a model read by load_model (``info``: its kind, method,
    schema version and training record), keys in the order a reader meets them; ``source``:
    the model file's name and sha256."""
    from ccl_cli import __version__

    kind, method = info["kind"], info["method"]
    training = info.get("training") or {}
    columns = training.get("data") if isinstance(training.get("data"), dict) else {}
    frame = columns.get("frame") if isinstance(columns.get("frame"), dict) else None
    doc: dict[str, Any] = {"format": FORMAT, "schema_version": SCHEMA_VERSION, "kind": kind,
                           "method": model.method if kind == "policy" else method}
    if kind == "constraint":  # what a controller needs first: k, the rows when constant, the frame
        doc["k"] = int(model.n_constraints_)
        rows = model.constant_rows()
        if rows is not None:
            doc["rows"] = rows
        doc["scope"] = model.local_to or "global"
    doc["frame"] = frame.get("base") if frame else None
    doc["state"] = _columns(getattr(model, "n_features_in_", None), columns, "states", "state_units")
    if frame:
        doc["state"]["forward_kinematics"] = frame
    doc["action"] = _columns(int(model.n_action_), columns, "actions", "action_units")
    if kind == "constraint":
        doc["constraint"] = constraint_body(model, method)
        doc["new_data"] = new_data(model, method)
        selection = getattr(model, "selection_", None) or {}
        doc["selection"] = {k: selection[k] for k in ("rule", "reason") if k in selection}
    elif kind == "nullspace":
        doc["nullspace"] = {"form": "basis_weights", "basis": basis(model.basis_), "weights": model.W_,
                            "formula": "w(x) = W β(x), weights W (q × K)"}
    else:
        doc["policy"] = policy_body(model)
    doc["source"] = {**source, "method": method, "model_schema_version": info.get("schema_version"),
                     "exported_by": f"ccl {__version__}"}
    doc["training"] = {k: training[k] for k in ("stage", "inputs", "config", "versions", "metrics")
                       if k in training}
    return clean(doc)


def _columns(n: int | None, columns: dict[str, Any], names_key: str, units_key: str) -> dict[str, Any]:
    """dimension, names and units of the states or actions (null where the model file does not
    record them: files written before ccl recorded its training data's columns)."""
    names, units = columns.get(names_key), columns.get(units_key)
    ok = isinstance(names, list) and (n is None or len(names) == n)
    return {"dimension": n, "names": names if ok else None,
            "units": units if ok and isinstance(units, list) and len(units) == len(names) else None}


def basis(b: Any) -> dict[str, Any]:
    """A fitted feature map β(x) (ALGORITHMS.md §2)."""
    state = b.state()
    if state["kind"] == "linear":
        return {"kind": "linear", "n_state": int(state["n_state"]), "formula": "β(x) = [x; 1] (K = p + 1)"}
    return {"kind": "rbf", "centres": state["centres"], "sigma2": float(state["sigma2"]), "formula": RBF}


def constraint_body(model: Any, method: str) -> dict[str, Any]:
    """The parameters of A(x) of a constraint model saved under ``method``, with its formula."""
    if method.startswith("per_demo:"):
        return per_demonstration(model, method.split(":", 1)[1])
    return _FORMS[method](model)


def _constant(model: Any) -> dict[str, Any]:
    return {"form": "constant", "rows": model.constant_rows(),
            "formula": "A(x) = rows, the same k × q matrix at every state", "projection": ORTHONORMAL}


def _none(model: Any) -> dict[str, Any]:
    return {"form": "none", "rows": [], "formula": "A has no rows (k = 0)", "projection": "identity"}


def _manifold(model: Any) -> dict[str, Any]:
    k = int(model.n_constraints_)
    return {"form": "manifold", "basis": model.family, "centre": model.centre_, "scale": float(model.scale_),
            "features": MANIFOLD_FEATURES[model.family], "levels": model.weights_[:, :k].T,
            "variation": model.variation_[:k],
            "formula": "z = (x − centre)/scale; the level functions h_j(x) = scale · levels_jᵀ φ(z) are "
                       "constant along a demonstration; A(x) = their gradients (∂φ/∂z)ᵀ levels_j, j = 1 … k, "
                       "orthonormalised in order (Gram–Schmidt, each row keeping its gradient's direction)",
            "projection": ORTHONORMAL}


def _angles(model: Any) -> dict[str, Any]:
    return {"form": "angles", "dimension": int(model.n_action_), "basis": basis(model.basis_),
            "weights": list(model.weights_), "formula": f"A(x): {ANGLES}; d = q", "projection": ORTHONORMAL}


def jacobian(spec: Any) -> dict[str, Any]:
    """Φ(x) = rows of a Jacobian at joint angles x: a built-in arm as its standard
    Denavit–Hartenberg table (:mod:`ccl_cli.learn.kinematics`), a robot as its URDF text."""
    from ccl_cli.learn.kinematics import ARMS

    spec = {"arm": spec} if isinstance(spec, str) else dict(spec)
    if spec.get("kind") == "robot" or "urdf" in spec:
        return {"kind": "urdf", "urdf": spec.get("urdf"), "base": spec.get("base"),
                "frame": spec.get("frame"), "rows": spec.get("rows"),
                "formula": "Φ(x) = the given rows of the geometric Jacobian [v; ω] of the chain's frame in "
                           "its base at joint angles x (the URDF's joints in order)"}
    arm = ARMS[spec["arm"]]()
    if spec["arm"] == "arm2":  # the planar arm: its Jacobian is the DH chain's rows v_x, v_y
        a, alpha, d, own = list(arm.lengths), [0.0, 0.0], [0.0, 0.0], 2
    else:
        a, alpha, d, own = arm.a, arm.alpha, arm.d, 6
    rows = [int(r) % own for r in spec["rows"]] if spec.get("rows") is not None else list(range(own))
    return {"kind": "dh", "arm": spec["arm"], "dh": {"a": a, "alpha": alpha, "d": d}, "rows": rows,
            "formula": DH}


def _known(model: Any) -> dict[str, Any]:
    return {"form": "known_features", "dimension": int(model.n_task_), "basis": basis(model.basis_),
            "weights": list(model.weights_), "features": jacobian(model.features),
            "formula": f"A(x) = Λ(x) Φ(x); Λ(x) (k × r): {ANGLES}; d = r", "projection": PSEUDO_INVERSE}


def monomials(p: int, degree: int) -> list[list[int]]:
    """Exponents (M, p) of a polynomial regressor's monomials, in ccl's order: 1, then each
    degree's combinations of the state's columns with replacement."""
    out = [[0] * p]
    for deg in range(1, degree + 1):
        out += [np.bincount(combo, minlength=p).tolist()
                for combo in combinations_with_replacement(range(p), deg)]
    return out


def regressors(model: Any, kind: Any) -> dict[str, Any]:
    """f(x) of a linear model's regressor family ``kind`` (identity / constant, polynomial, rbf)."""
    if kind in ("identity", "constant"):
        return {"kind": "constant", "formula": "f(x) = [1]"}
    if kind == "polynomial":
        return {"kind": "polynomial", "monomials": monomials(int(model.n_features_in_), int(model.degree)),
                "formula": "f_m(x) = Π_i x_i^monomials[m][i]"}
    return {"kind": "rbf", "basis": basis(model.basis_), "formula": "f(x) = β(x)"}


def _linear(model: Any) -> dict[str, Any]:
    q, k = int(model.n_action_), int(model.n_constraints_)
    if isinstance(model.regressors, dict):  # a robot's Jacobian rows: A(x) = W J(x)[rows]
        body = {"form": "linear", "regressors": {"kind": "jacobian", "features": jacobian(model.regressors)},
                "weights": model.W_, "formula": "A(x) = weights Φ(x), weights k × r, Φ(x) r × q"}
    else:
        body = {"form": "linear", "regressors": regressors(model, model.regressors),
                "weights": model.W_.reshape(k, -1, q).transpose(1, 0, 2),
                "formula": "A(x) = Σ_m f_m(x) weights[m], weights M × k × q"}
    body["projection"] = PSEUDO_INVERSE
    if model.Wb_ is not None:
        body["task"] = {"regressors": regressors(model, model.task_regressors), "weights": model.Wb_,
                        "formula": "b(x) = weights f_b(x) (k); the task part v(x) = A(x)⁺ b(x), singular "
                                   "values below 1e-15 × the largest dropped"}
    return body


def _windows(model: Any) -> dict[str, Any]:
    """A constant A per window, per segment or per demonstration (PerWindow, PerSegment)."""
    per_demo = model.window_ is None
    table = model.windows_.astype(int)
    ends = table[:, 2] if table.shape[1] == 3 else table[:, 1] + 1
    entries = []
    for i, (demo, start, end) in enumerate(model.spans()):
        entry: dict[str, Any] = {"demonstration": int(demo)}
        if not per_demo:
            entry["blocks"] = [int(table[i, 1]), int(ends[i])]
        entries.append({**entry, "start": start, "end": None if per_demo else end, "rows": model.A_[i]})
    lookup = ("a sample of demonstration d takes the rows of d's entry" if per_demo
              else BLOCK_LOOKUP.format(what="entry"))
    return {"form": "windows", "per": model.per, "block": None if per_demo else float(model.window_),
            "entries": entries, "lookup": lookup, "formula": "A(x) = the rows of the sample's entry",
            "projection": ORTHONORMAL}


def _stretches(model: Any) -> dict[str, Any]:
    """Constant rows that hold in some phases of each demonstration (ConstraintInStretches): its
    blocks as runs of consecutive blocks with the same label."""
    blocks = model.blocks_.astype(int)
    cut = np.flatnonzero((blocks[1:, 0] != blocks[:-1, 0]) | (blocks[1:, 2] != blocks[:-1, 2])) + 1
    phases = []
    for run in np.split(np.arange(len(blocks)), cut):
        (demo, first, on), last = blocks[run[0], [0, 1, 2]], blocks[run[-1], 1] + 1
        phases.append({"demonstration": int(demo), "blocks": [int(first), int(last)],
                       "start": first * model.block, "end": last * model.block, "holds": bool(on)})
    return {"form": "stretches", "rows": model.A_, "block": float(model.block), "phases": phases,
            "share": float(model.share_), "lookup": BLOCK_LOOKUP.format(what="phase"),
            "formula": "A(x) = rows in a phase that holds, rows of zeros elsewhere",
            "projection": ORTHONORMAL}


def per_demonstration(model: Any, inner: str) -> dict[str, Any]:
    """One model per demonstration (PerDemonstration): each demonstration's own A(x)."""
    entries = [{"demonstration": int(d), "start": 0.0, "end": None, "k": int(m.n_constraints_),
                "constraint": constraint_body(m, inner)}
               for d, m in sorted(model.models_by_demonstration().items())]
    return {"form": "per_demonstration", "estimator": inner, "entries": entries,
            "lookup": "a sample of demonstration d takes the A(x) of d's entry",
            "formula": "A(x) = the entry's constraint at x (rows of zeros pad an entry with fewer than k "
                       "rows)", "projection": "per_entry"}


def _contact(model: Any) -> dict[str, Any]:
    """One row per contact stretch a force showed (ContactPhases), none elsewhere."""
    entries = [{"demonstration": int(d), "start": a, "end": b, "rows": rows}
               for (d, a, b), rows in zip(model.spans_, model.A_, strict=True)]
    return {"form": "contact", "entries": entries,
            "lookup": "a sample of demonstration d at time t takes the rows of the entry of d with start ≤ "
                      "t ≤ end; none outside every entry",
            "formula": "A(x) = the entry's row in a contact stretch, rows of zeros elsewhere",
            "projection": ORTHONORMAL}


_FORMS = {"nhat": _constant, "none": _none, "manifold": _manifold, "alpha": _angles, "lambda": _known,
          "linear": _linear, "per_window": _windows, "per_segment": _windows, "stretches": _stretches,
          "contact": _contact}


# -- a recording the model has not seen -----------------------------------------------------------
def new_data(model: Any, method: str) -> dict[str, Any]:
    """The model's rule for a recording it has not seen (``new_data_rule``) and, for a model per
    stretch, what the rule fits on it (``fit``); ``reproducible``: the reference evaluator
    (docs/export.md) applies the rule from this file alone."""
    from ccl_cli.learn.constraint import noise_rank, stretches
    from ccl_cli.learn.constraint.manifold import RIDGE
    from ccl_cli.learn.defaults import DERIVATIVE_HALF_SPAN_S, DERIVATIVE_MAX_WINDOW
    from ccl_cli.learn.noise import MAD_NORMAL

    out: dict[str, Any] = {**model.new_data_rule.as_dict(), "reproducible": True}
    k = int(model.n_constraints_)
    if method in ("per_window", "per_segment"):
        out["fit"] = {"method": "windows" if method == "per_window" else "segments", "k": k,
                      "window": model.window, "shrinkage": float(model.shrinkage)}
        if method == "per_segment":
            out["fit"].update(block=float(model.block), penalty=float(model.penalty))
    elif method == "stretches":
        out["fit"] = {"method": "classify", "block": float(model.block), "margin": noise_rank.MARGIN,
                      "share_block": stretches.SHARE_BLOCK,
                      "noise": {"mad_normal": MAD_NORMAL, "derivative_half_span": DERIVATIVE_HALF_SPAN_S,
                                "derivative_max_window": DERIVATIVE_MAX_WINDOW, "derivative_order": 2}}
    elif method == "contact":
        out["reproducible"] = False
        out["fit"] = {"method": "classify", "block": float(model.block),
                      "why": "the contact rows' blocks classified by ccl's noise rule: apply the model to a "
                             "new recording with ccl predict"}
    elif method.startswith("per_demo:"):
        est, inner = model.estimator, method.split(":", 1)[1]
        fixed = getattr(est, "n_constraints", None)
        out["fit"] = {"method": inner, "k": fixed}
        if inner == "manifold":
            out["fit"].update(basis=est.family, ridge=RIDGE)
        out["reproducible"] = fixed is not None and (
            inner == "manifold" or (inner == "nhat" and est.method == "closed_form"))
        if not out["reproducible"]:
            out["fit"]["why"] = (f"the {inner} learner's own fit (its rule chooses k, or it iterates): apply "
                                 "the model to a new recording with ccl predict")
    return out


# -- policy -------------------------------------------------------------------------------------
def policy_body(model: Any) -> dict[str, Any]:
    """π(x) of a policy learner: Wᵀβ(x), or lwpi's locally weighted linear models."""
    if model.method == "lwpi":
        return {"form": "lwpi", "basis": basis(model.basis_), "weights": model.W_,
                "formula": "π(x) = Σ_c β_c(x) W_cᵀ [x; 1], weights W (K × (p + 1) × q): the local linear "
                           "model of each centre, weighted by the normalised features"}
    return {"form": "basis_weights", "basis": basis(model.basis_), "weights": model.W_,
            "formula": "π(x) = Wᵀ β(x), weights W (K × q)"}


# -- writing ------------------------------------------------------------------------------------
def clean(value: Any) -> Any:
    """``value`` as plain JSON types: arrays as nested lists, numpy scalars as numbers, tuples
    as lists, non-finite floats as null (a JSON or YAML reader in any language takes the rest)."""
    if isinstance(value, dict):
        return {str(k): clean(v) for k, v in value.items()}
    if isinstance(value, list | tuple):
        return [clean(v) for v in value]
    if isinstance(value, np.ndarray):
        return clean(value.tolist())
    if isinstance(value, np.integer | np.bool_):
        return value.item()
    if isinstance(value, float | np.floating):
        return float(value) if math.isfinite(value) else None
    return value


_SCALAR = r'(?:"(?:[^"\\]|\\.)*"|[-+0-9.eE]+|null|true|false)'
_SURROGATE = re.compile("[\udc80-\udcff]")
_FLAT = re.compile(rf"\[\s*({_SCALAR}(?:,\s*{_SCALAR})*)\s*\]")


def dump(doc: dict[str, Any], style: str) -> str:
    """The document as YAML (block style, each innermost list of numbers or names on one line) or
    JSON (indented, the same lists on one line); numbers written so that they read back exactly."""
    if style == "json":
        text = json.dumps(doc, indent=2, ensure_ascii=False, allow_nan=False)
        # a file name that is not UTF-8 (os.fsdecode's surrogate escapes) as a \udcNN escape, as
        # YAML writes it and run.json does: UTF-8 cannot encode a lone surrogate
        text = _SURROGATE.sub(lambda m: f"\\u{ord(m.group(0)):04x}", text)
        return _FLAT.sub(lambda m: "[" + re.sub(r",\n\s*", ", ", m.group(1)) + "]" if "\n" in m.group(0)
                         else m.group(0), text) + "\n"
    import yaml

    class Dumper(yaml.SafeDumper):
        """Mappings in block style, lists of scalars on one line."""

    def listed(dumper: yaml.SafeDumper, data: list) -> yaml.Node:
        flat = all(not isinstance(v, dict | list) for v in data)
        return dumper.represent_sequence("tag:yaml.org,2002:seq", data, flow_style=flat)

    Dumper.add_representer(list, listed)
    return yaml.dump(doc, Dumper=Dumper, sort_keys=False, default_flow_style=False, allow_unicode=True,
                     width=100)
