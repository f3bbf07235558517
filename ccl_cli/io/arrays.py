"""From arrays (HDF5 datasets, MATLAB variables, text matrices) to demonstrations.

Array formats give, per demonstration, a state matrix, optionally an action matrix and
a time vector. What is common to them lives here: orientation (``samples: rows`` — one
sample per row, as NumPy/HDF5 writers store it — or ``columns``, as MATLAB code and the
original C library do), a demo-index vector split into demonstrations, time from a rate,
non-finite samples, and actions derived from the state (see :mod:`ccl_cli.io.derivative`).
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations, Derivative, Repair, stamps_assumed
from ccl_cli.errors import InputError
from ccl_cli.io import forces
from ccl_cli.io.derivative import derive_actions
from ccl_cli.io.options import UNIT_NS, DataOptions, DemoOptions, TimeOptions
from ccl_cli.io.segment import CUTS, cut
from ccl_cli.io.stored_faults import repair_recording
from ccl_cli.io.task_space import to_task_space

NAME_ATTRS = ("names", "column_names", "joint_names", "labels", "fields")


@dataclass
class Variable:
    """One array as read, with where it came from and how its samples lie."""

    values: np.ndarray
    where: str
    samples: str | None = None
    names: list[str] | None = None


@dataclass
class Part:
    """One demonstration: state (n, p), action (n, q) or None, time (n,) seconds or None; the
    arrays read beside the state, sample for sample (``extra``: the force and the tool's
    orientation, :mod:`ccl_cli.io.forces`)."""

    X: np.ndarray
    U: np.ndarray | None
    t: np.ndarray | None
    label: str
    meta: dict[str, Any] = field(default_factory=dict)
    extra: dict[str, np.ndarray] = field(default_factory=dict)


def as_numeric(values: Any, where: str, keep_int: bool = False) -> np.ndarray:
    """``values`` as a float64 array (int64 if ``keep_int`` and integer), or a one-line
    error saying what it is instead."""
    arr = np.asarray(values)
    if arr.dtype == object or not (np.issubdtype(arr.dtype, np.number) or arr.dtype == bool):
        kind = "text" if arr.dtype.kind in "SUa" else f"dtype {arr.dtype}"
        raise InputError(f"{where}: not numeric ({kind})")
    if np.iscomplexobj(arr):
        raise InputError(f"{where}: complex numbers are not supported")
    if arr.ndim > 2:
        raise InputError(f"{where}: {arr.ndim}-D array {arr.shape}; expected a vector or a matrix")
    if keep_int and np.issubdtype(arr.dtype, np.integer):
        return arr.astype(np.int64)
    return arr.astype(float)


def _is_vector(shape: tuple[int, ...]) -> bool:
    return len(shape) == 1 or (len(shape) == 2 and 1 in shape)


def _side(var: Variable, default: str | None) -> str | None:
    """rows, columns, vector (either way) or None (to be inferred)."""
    if var.samples is not None:
        return var.samples
    if _is_vector(var.values.shape):
        return "vector"
    return default


def orient(variables: dict[str, Variable], default: str | None, where: str) -> dict[str, np.ndarray]:
    """Each variable as (n, d), one sample per row, all with the same n.

    ``samples`` says which axis holds the samples; when it is not given (and ``default``
    is None) the axis is the one whose length the other variables share; a matrix whose
    two sides both fit (square) or a set of variables that allows two sample counts is
    refused with the key to set. Vectors (1-D, or one side 1) fit either way.
    """
    sides = {}
    for key, var in variables.items():
        if var.values.ndim == 0 or var.values.size == 0:
            raise InputError(f"{var.where}: empty or scalar; expected a matrix of samples")
        sides[key] = _side(var, default)
    known: dict[str, int] = {}
    for key, var in variables.items():
        shape, side = var.values.shape, sides[key]
        if side == "vector":
            known[key] = int(var.values.size)
        elif side is not None:
            known[key] = shape[0] if side == "rows" or len(shape) == 1 else shape[1]
    if known:
        counts = set(known.values())
        if len(counts) > 1:
            desc = ", ".join(f"{_name(variables[k])} has {n}" for k, n in known.items())
            raise InputError(f"{where}: the variables disagree on the number of samples ({desc}); "
                             "check samples: rows|columns")
        n = counts.pop()
    else:
        common = set.intersection(*(set(v.values.shape) for v in variables.values()))
        if len(common) != 1:
            shapes = ", ".join(f"{_name(v)} {_shape(v.values)}" for v in variables.values())
            raise InputError(f"{where}: cannot tell which side holds the samples ({shapes}); "
                             "set samples: rows or samples: columns")
        n = common.pop()
    out = {}
    for key, var in variables.items():
        arr, side = var.values, sides[key]
        if side is None:
            rows_fit, cols_fit = arr.shape[0] == n, arr.shape[1] == n
            if rows_fit and cols_fit:
                raise InputError(f"{var.where}: square {_shape(arr)} matrix; "
                                 "set samples: rows or samples: columns")
            if not (rows_fit or cols_fit):
                raise InputError(f"{var.where}: shape {_shape(arr)} has no side of length {n} "
                                 "(the samples of the other variables)")
            side = "rows" if rows_fit else "columns"
        if side == "vector" or arr.ndim == 1:
            out[key] = arr.reshape(-1, 1)
        else:
            out[key] = arr if side == "rows" else arr.T
    return out


def _name(var: Variable) -> str:
    """The variable's own part of ``where`` (after the file name)."""
    return var.where.rsplit(": ", 1)[-1]


def _shape(arr: np.ndarray) -> str:
    return "×".join(map(str, arr.shape))


def split_by_index(arrays: dict[str, np.ndarray], demo: np.ndarray, where: str
                   ) -> list[tuple[str, dict[str, np.ndarray]]]:
    """Rows grouped by a demo-index vector (ids in order of first appearance; a demo's
    samples keep their order) → [(label, arrays of that demo)]."""
    ids = np.asarray(demo).ravel()
    if not np.all(np.isfinite(ids)) or not np.all(ids == np.round(ids)):
        raise InputError(f"{where}: the demo index must hold integers")
    ids = ids.astype(np.int64)
    uniq, first, inverse = np.unique(ids, return_index=True, return_inverse=True)
    rank = np.argsort(np.argsort(first))[inverse]  # demo order = order of first appearance
    order = np.argsort(rank, kind="stable")
    bounds = np.flatnonzero(np.diff(rank[order])) + 1
    chunks = np.split(order, bounds)
    return [(f"demo {int(ids[c[0]])}", {k: v[c] for k, v in arrays.items()}) for c in chunks]


def chunk_times(chunks: list[tuple[str, dict[str, np.ndarray]]], time: TimeOptions, where: str
                ) -> tuple[list[np.ndarray], int, str]:
    """Seconds per demonstration, the time origin in ns, and what was used.

    From the ``time`` arrays of the chunks scaled by ``time.unit`` (integer stamps without
    a unit: ≥ 1e15 means ns, else s, as for CSV), or ``k / time.rate``. Integer stamps are
    made relative to the file's first stamp in integer arithmetic (exact at epoch scale);
    that stamp is the origin.
    """
    unit, rate = time.unit, time.rate
    if "time" not in chunks[0][1]:
        if rate is None:
            raise InputError(f"{where}: no time given; set data.time.rate (Hz) or the time dataset/variable")
        return [np.arange(a["state"].shape[0]) / float(rate) for _, a in chunks], 0, f"rate {rate} Hz"
    raws = [a["time"][:, 0] for _, a in chunks]
    if np.issubdtype(raws[0].dtype, np.integer):
        origin = int(raws[0][0])
        if unit is None:
            unit = "ns" if max(int(np.abs(r).max()) for r in raws) >= 10**15 else "s"
        scale = UNIT_NS[unit] / 1e9
        return ([(r.astype(np.int64) - origin).astype(float) * scale for r in raws],
                origin * UNIT_NS[unit], f"integer stamps in {unit}")
    unit = unit or "s"
    return [r.astype(float) * (UNIT_NS[unit] / 1e9) for r in raws], 0, f"stamps in {unit}"


def names_for(label: str, d: int, given: list[str] | None) -> list[str]:
    if given is not None and len(given) == d:
        return [str(g) for g in given]
    return [label] if d == 1 else [f"{label}[{j}]" for j in range(d)]


def select_columns(mat: np.ndarray, names: list[str], columns: list[Any] | None, where: str
                   ) -> tuple[np.ndarray, list[str]]:
    """Columns of ``mat`` by 0-based index or by name."""
    if not columns:
        return mat, names
    idx = []
    for c in columns:
        if isinstance(c, int) or (isinstance(c, str) and c.isdigit() and c not in names):
            k = int(c)
            if not 0 <= k < mat.shape[1]:
                raise InputError(f"{where}: column {k} out of range (0..{mat.shape[1] - 1})")
        elif c in names:
            k = names.index(c)
        else:
            raise InputError(f"{where}: column {c!r} not found (names: {', '.join(names)})")
        idx.append(k)
    return mat[:, idx], [names[k] for k in idx]


def pick_columns(parts: list[Part], attr: str, names: list[str], columns: list[Any] | None,
                 where: str) -> list[str]:
    """Keep ``columns`` of every part's ``attr`` (X or U) in place; the names kept."""
    kept = names
    for part in parts:
        values, kept = select_columns(getattr(part, attr), names, columns, where)
        setattr(part, attr, values)
    return kept


def pick_extra(parts: list[Part], key: str, columns: list[Any] | None, where: str) -> None:
    """Keep ``columns`` of every part's ``extra[key]`` in place (by 0-based index, or by the
    numbered names :func:`names_for` gives)."""
    if not parts or key not in parts[0].extra:
        raise InputError(f"{where}: not read (name its dataset or variable)")
    names = names_for(key, parts[0].extra[key].shape[1], None)
    for part in parts:
        part.extra[key] = select_columns(part.extra[key], names, columns, where)[0]


def named_parts(chunks: list[tuple[str, dict[str, np.ndarray]]], options: DataOptions, where: str,
                labels: dict[str, str], given: dict[str, list[str] | None], derive: bool
                ) -> tuple[list[Part], list[str], list[str] | None, int, str]:
    """(label, arrays) chunks → one :class:`Part` per demonstration with its seconds
    (:func:`chunk_times`), and the state and action column names: ``given[key]`` when it
    fits, else ``labels[key]`` numbered (:func:`names_for`), then the options' ``columns``
    (:func:`pick_columns`). Returns (parts, state names, action names — None when derived —,
    time origin ns, what the time was read from)."""
    times, origin, time_used = chunk_times(chunks, options.time, where)
    parts = [Part(a["state"], a.get("action"), t, label, extra={k: a[k] for k in forces.KEYS if k in a})
             for (label, a), t in zip(chunks, times, strict=True)]
    for key, selection in forces.selections(options).items():  # the force's own columns
        pick_extra(parts, key, selection.columns, f"{where}: {forces.option_path(key)}")

    def names(key: str, attr: str) -> list[str]:
        default = names_for(labels[key], getattr(parts[0], attr).shape[1], given.get(key))
        return pick_columns(parts, attr, default, getattr(options, key).columns, where)

    named = given.get("state") is not None and len(given["state"]) == parts[0].X.shape[1]
    state_names, action_names = names("state", "X"), None if derive else names("action", "U")
    fk = options.state.forward_kinematics
    if fk is not None:  # joints → end-effector pose; a recorded joint velocity → v = J_p(q) q̇
        log_names = state_names if named else None  # unnamed columns: the chain's joint order
        for part in parts:  # a loop over demonstrations; each call batched over samples
            part.X, part.U, joints = to_task_space(part.X, part.U, fk, log_names, f"{where}: {part.label}")
            part.meta["forward_kinematics"] = joints.describe()
        state_names = joints.names
        action_names = None if derive else [f"v{n}" for n in joints.names]
    return parts, state_names, action_names, origin, time_used


def cut_parts(parts: list[Part], demos: DemoOptions, where: str, passes: list[np.ndarray] | None = None
              ) -> list[Part]:
    """Each demonstration cut into the phases the ``demos`` options ask for
    (:func:`ccl_cli.io.segment.cut`: split_on_gap, ranges — per demonstration keyed by its
    position —, where, min_duration, window); ``passes``: per part, where the ``demos.where``
    signal passes (n,) bool. A piece's label gives its span in seconds."""
    cuts = DemoOptions(**{k: getattr(demos, k) for k in CUTS if getattr(demos, k) is not None})
    if not cuts.given():
        return parts
    out: list[Part] = []
    first = 0
    for k, part in enumerate(parts):  # a loop over demonstrations; the cut is batched over samples
        ids, n_base = cut(part.t, cuts, f"{where}: {part.label}", passes[k] if passes else None, first)
        first += n_base
        for j in range(int(ids.max()) + 1 if (ids >= 0).any() else 0):
            rows = ids == j
            t = part.t[rows]
            out.append(Part(part.X[rows], part.U[rows] if part.U is not None else None, t,
                            f"{part.label} [{t[0]:.4g}, {t[-1]:.4g}] s", dict(part.meta),
                            {k: v[rows] for k, v in part.extra.items()}))
    if not out:
        raise InputError(f"{where}: no samples left after the demos cuts "
                         f"({', '.join('demos.' + k for k in sorted(cuts.given()))})")
    return out


def assemble(parts: list[Part], options: DataOptions, where: str, state_names: list[str],
             action_names: list[str] | None, meta: dict[str, Any]) -> Demonstrations:
    """Per-demonstration arrays → one :class:`Demonstrations` (demo ids in part order).

    Non-finite samples are dropped (``nonfinite: drop``) or refused (``fail``);
    time must increase strictly within each demonstration; with ``action: {derive:
    state}`` U is the local-polynomial derivative of X on the real timestamps.
    """
    if not parts:
        raise InputError(f"{where}: no demonstrations found")
    policy = options.nonfinite
    p = parts[0].X.shape[1]
    q = parts[0].U.shape[1] if parts[0].U is not None else None
    Xs, Us, Ts, demo, dropped = [], [], [], [], 0
    extras: dict[str, list[np.ndarray]] = {k: [] for k in parts[0].extra}
    for k, part in enumerate(parts):
        here = f"{where}: {part.label}"
        if part.X.shape[1] != p or (q is not None and part.U.shape[1] != q):
            got = (part.X.shape[1], part.U.shape[1] if part.U is not None else None)
            raise InputError(f"{here}: dimensions {got} differ from the first demonstration's {(p, q)}")
        ok = np.isfinite(part.X).all(1)
        if part.U is not None:
            ok &= np.isfinite(part.U).all(1)
        for value in part.extra.values():
            ok &= np.isfinite(value).all(1)
        if not ok.all():
            if policy == "fail":
                raise InputError(f"{here}: {int((~ok).sum())} samples contain NaN or inf "
                                 f"(first at sample {int(np.argmax(~ok))}); set data.nonfinite: drop")
            dropped += int((~ok).sum())
        if not ok.any():
            raise InputError(f"{here}: no samples left")
        t = part.t[ok]
        if not np.isfinite(t).all():
            raise InputError(f"{here}: time contains NaN or inf")
        Xs.append(part.X[ok])
        Us.append(part.U[ok] if part.U is not None else None)
        Ts.append(t)
        for key, value in part.extra.items():
            extras[key].append(value[ok])
        demo.append(np.full(int(ok.sum()), k))
    X, t, ids = np.concatenate(Xs), np.concatenate(Ts), np.concatenate(demo)
    U = np.concatenate(Us) if q is not None else None
    fixed = repair_recording(t, X, U, ids, options.faults)  # before actions are derived
    repair = Repair.untouched(len(t))
    extra = {k: np.concatenate(v) for k, v in extras.items()}
    if fixed is not None:
        t, X, U, ids = fixed.t, fixed.X, fixed.U, ids[fixed.keep]
        extra = {k: v[fixed.keep] for k, v in extra.items()}
        meta["faults"] = fixed.report
        repair = fixed.record
    bad = np.flatnonzero((np.diff(t) <= 0) & (ids[1:] == ids[:-1]))
    if len(bad):
        k = int(bad[0]) + 1
        first = int(np.argmax(ids == ids[k]))
        raise InputError(f"{where}: {parts[ids[k]].label}: time is not strictly increasing at sample "
                         f"{k - first} ({t[k - 1]!r} s then {t[k]!r} s)")
    how = Derivative()  # recorded actions of a table: not said
    if U is None:
        paced = stamps_assumed(meta.get("time"))  # stamps from an assumed rate
        U, meta["action"] = derive_actions(t, X, ids, options.action, paced=paced)
        how = Derivative.from_record(meta["action"])
        action_names = [f"d{n}/dt" for n in state_names]
    if dropped:
        meta["dropped_nonfinite"] = dropped
    meta["demos"] = [part.label for part in parts]
    units = None
    if "forward_kinematics" in parts[0].meta:
        meta["forward_kinematics"] = parts[0].meta["forward_kinematics"]
        units = meta["forward_kinematics"]["units"]
    data = Demonstrations(X=X, U=U, demo=ids, t=t, state_names=state_names, action_names=action_names,
                          state_units=units, action_units=[f"{u}/s" for u in units] if units else None,
                          metadata=meta, derivative=how, repair=repair)
    if options.force is not None:
        force = forces.base_frame(extra["force"], extra.get("orientation"), options.force, where)
        data = forces.finish(data, force, options)
    return data
