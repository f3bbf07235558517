"""MATLAB ``.mat`` files: v5/v7 (scipy.io.loadmat) and v7.3 (HDF5, via h5py).

Configured by variable names, dotted for struct fields::

    format: mat
    state:  {variable: X, samples: columns}   # or data.X (a struct field)
    action: {variable: U, samples: columns}   # or {derive: state}
    time:   {rate: 500}                       # or {variable: t}
    demos:  {variable: demo}                  # a demo id per sample (matrices only)

A cell array holds one demonstration per cell (MATLAB's linear order); a struct array
one per element; a matrix is one demonstration, or several with ``demos.variable``.
``samples: columns`` (one sample per column, as the original library stores data) or
``rows``; when not given, the side whose length the other variables share, refused
when ambiguous.

v7.3 files are HDF5 behind a 512-byte user block whose text starts "MATLAB 7.3 MAT-file";
MATLAB writes every array transposed (column-major), marks each with a ``MATLAB_class``
attribute and stores cell arrays as object references into ``/#refs#``. Only numeric and
logical arrays, cells and structs are read: MATLAB objects, function handles and other
opaque classes are refused, never loaded.
"""

from __future__ import annotations

import os
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io import forces
from ccl_cli.io.arrays import Variable, as_numeric, assemble, cut_parts, named_parts, orient, split_by_index
from ccl_cli.io.formats.mat5_elements import check_variable
from ccl_cli.io.h5.access import attr_str, attr_value, error_text
from ccl_cli.io.h5.listing import list_hdf5, truncate
from ccl_cli.io.h5.probe import open_hdf5
from ccl_cli.io.limits import check_claim, max_bytes
from ccl_cli.io.options import DataOptions, SignalOptions
from ccl_cli.io.reader import ReaderBase, Recording
from ccl_cli.io.segment import CUTS
from ccl_cli.io.sniff import MAT5_MAGIC, MAT73_MAGIC, read_head
from ccl_cli.io.summary import summary

NUMERIC_CLASSES = {"double", "single", "int8", "uint8", "int16", "uint16", "int32", "uint32",
                   "int64", "uint64", "logical"}
CONTAINERS = {"cell", "struct"}
#: cells and structs nested deeper than this are refused (references may loop)
MAX_DEPTH = 32

Value = np.ndarray | list  # a numeric (or char) array, or one value per cell / struct element


def _refuse(where: str, cls: str) -> InputError:
    return InputError(f"{where}: a MATLAB {cls}; ccl reads only numeric arrays, cells and structs "
                      "and never loads MATLAB objects or function handles")


# -- v5 / v7 ------------------------------------------------------------------------------
class _V5:
    def __init__(self, path: Path) -> None:
        from scipy.io import whosmat

        self.path = path
        try:
            self.whos = {name: (tuple(shape), cls) for name, shape, cls in whosmat(str(path))}
        except Exception as exc:  # scipy raises many types on corrupt files
            raise InputError(f"{path}: cannot read as a MATLAB file ({type(exc).__name__}: {exc})") from None

    def variables(self) -> list[tuple[str, tuple[int, ...], str]]:
        return [(name, shape, cls) for name, (shape, cls) in self.whos.items()]

    def load(self, name: str) -> Any:
        """Variable ``name`` as scipy reads it (structs as record arrays, cells as object arrays),
        its declared size checked first (a sparse matrix: the dense array it becomes)."""
        from scipy.io import loadmat

        shape, cls = self.whos[name]
        if cls in NUMERIC_CLASSES | {"char", "sparse"}:
            check_claim(f"{self.path}: {name}", f"the {cls} variable", shape, 8,
                        None if cls == "sparse" else os.path.getsize(self.path))
        check_variable(self.path, name, shape, cls in CONTAINERS, max_bytes())

        try:
            return loadmat(str(self.path), variable_names=[name], squeeze_me=False,
                           struct_as_record=True, chars_as_strings=False)[name]
        except Exception as exc:  # scipy raises many types on corrupt files
            raise InputError(f"{self.path}: cannot read variable {name!r} "
                             f"({type(exc).__name__}: {exc})") from None

    def get(self, dotted: str) -> Value:
        where = f"{self.path}: {dotted}"
        name, *fields = dotted.split(".")
        if name not in self.whos:
            raise InputError(f"{self.path}: variable {name!r} not found "
                             f"(variables: {', '.join(self.whos) or 'none'})")
        cls = self.whos[name][1]
        if cls not in NUMERIC_CLASSES | CONTAINERS | {"char", "sparse"}:
            raise _refuse(where, cls)
        return self._walk(self.load(name), fields, name, where)

    def _walk(self, value: Any, fields: list[str], at: str, where: str) -> Value:
        from scipy.io.matlab import MatlabFunction, MatlabObject, MatlabOpaque

        if isinstance(value, MatlabObject | MatlabFunction | MatlabOpaque):
            raise _refuse(f"{self.path}: {at}", type(value).__name__)
        if isinstance(value, list):
            return [self._walk(v, fields, f"{at}({k + 1})", where) for k, v in enumerate(value)]
        if hasattr(value, "tocsc"):  # scipy.sparse: its dense size checked before it exists
            check_claim(f"{self.path}: {at}", "the sparse matrix", value.shape, 8)
            value = value.toarray()
        arr = np.asarray(value)
        if arr.dtype.names:  # struct (array)
            if not fields:
                raise InputError(f"{self.path}: {at} is a struct; name a field (fields: "
                                 f"{', '.join(arr.dtype.names)}), e.g. {at}.{arr.dtype.names[0]}")
            field, rest = fields[0], fields[1:]
            if field not in arr.dtype.names:
                raise InputError(f"{self.path}: {at} has no field {field!r} "
                                 f"(fields: {', '.join(arr.dtype.names)})")
            elems = arr.ravel(order="F")
            if len(elems) == 1:
                return self._walk(elems[0][field], rest, f"{at}.{field}", where)
            return [self._walk(e[field], rest, f"{at}({k + 1}).{field}", where) for k, e in enumerate(elems)]
        if arr.dtype == object:  # cell array: one value per cell, MATLAB linear order (a field: of each)
            cells = arr.ravel(order="F")
            return [self._walk(c, fields, f"{at}{{{k + 1}}}", where) for k, c in enumerate(cells)]
        if fields:
            raise InputError(f"{self.path}: {at} is not a struct (cannot take field {fields[0]!r})")
        return arr


# -- v7.3 (HDF5) --------------------------------------------------------------------------
def _cls(obj) -> str:
    """The ``MATLAB_class`` attribute ('' when absent; a damaged one is an InputError)."""
    return attr_str(obj.attrs, "MATLAB_class", f"{obj.file.filename}:{obj.name}", "")


class _V73:
    def __init__(self, path: Path) -> None:
        self.path = path
        self.f = open_hdf5(path, "MATLAB v7.3 file")

    def close(self) -> None:
        self.f.close()

    def variables(self) -> list[tuple[str, tuple[int, ...], str]]:
        out = []
        for name, obj in self.f.items():
            if name.startswith("#"):
                continue
            out.append((name, _matlab_shape(obj), _cls(obj)))
        return out

    def get(self, dotted: str) -> Value:
        name, *fields = dotted.split(".")
        if name.startswith("#") or name not in self.f:
            names = ", ".join(n for n in self.f if not n.startswith("#")) or "none"
            raise InputError(f"{self.path}: variable {name!r} not found (variables: {names})")
        return self._walk(self.f[name], fields, name)

    def _walk(self, obj, fields: list[str], at: str, depth: int = 0) -> Value:
        import h5py

        where = f"{self.path}: {at}"
        if depth > MAX_DEPTH:  # cells of cells, or references that loop
            raise InputError(f"{where}: cells or structs nested deeper than {MAX_DEPTH} levels; refused")
        cls = _cls(obj)
        if cls == "struct" or (isinstance(obj, h5py.Group) and not cls):
            if not isinstance(obj, h5py.Group):
                raise InputError(f"{where}: struct stored as {type(obj).__name__}; not supported")
            members = [k for k in obj if not k.startswith("#")]
            if not fields:
                raise InputError(f"{where} is a struct; name a field (fields: {', '.join(members)})")
            field, rest = fields[0], fields[1:]
            if field not in obj:
                raise InputError(f"{where} has no field {field!r} (fields: {', '.join(members)})")
            child = obj[field]
            if isinstance(child, h5py.Dataset) and child.dtype == h5py.ref_dtype and _cls(child) != "cell":
                refs = self._read(child, f"{where}.{field}").ravel()  # struct array: a reference per element
                if len(refs) > 1:
                    return [self._walk(self._deref(r, where), rest, f"{at}({k + 1}).{field}", depth + 1)
                            for k, r in enumerate(refs)]
                if not len(refs):
                    raise InputError(f"{where}.{field}: a struct array without elements")
                return self._walk(self._deref(refs[0], where), rest, f"{at}.{field}", depth + 1)
            return self._walk(child, rest, f"{at}.{field}", depth + 1)
        if fields and cls != "cell":
            raise InputError(f"{where} is not a struct (cannot take field {fields[0]!r})")
        if not isinstance(obj, h5py.Dataset):
            raise InputError(f"{where}: a group of MATLAB class {cls!r}; not readable")
        if cls == "cell":  # one value per cell (a field: of each cell's struct)
            if obj.dtype != h5py.ref_dtype:
                raise InputError(f"{where}: a cell must hold object references, got {obj.dtype} "
                                 "(damaged file?)")
            refs = self._read(obj, where).ravel()  # stored transposed: C order is MATLAB's linear order
            return [self._walk(self._deref(r, where), fields, f"{at}{{{k + 1}}}", depth + 1)
                    for k, r in enumerate(refs)]
        if cls not in NUMERIC_CLASSES | {"char"} or \
                attr_value(obj.attrs, "MATLAB_object_decode", where, None) is not None:
            raise _refuse(where, cls or "value without MATLAB_class")
        if _empty(obj):
            return np.zeros((0, 0))
        raw = self._read(obj, where)
        if raw.dtype.names and set(raw.dtype.names) == {"real", "imag"}:
            raise InputError(f"{where}: complex numbers are not supported")
        if cls == "char":
            return np.asarray(raw, dtype=np.uint16).astype("U1") if raw.size else np.array([], "U1")
        return np.asarray(raw).T  # back to MATLAB's orientation

    def _deref(self, ref: Any, where: str) -> Any:
        """The dataset or group an object reference points to (a null or dangling one, or one
        to anything else — a named datatype: InputError)."""
        import h5py

        try:
            if not ref:
                raise ValueError("null reference")
            found = self.f[ref]
        except (KeyError, ValueError, TypeError, OSError, RuntimeError) as exc:
            raise InputError(f"{where}: a reference that cannot be followed ({error_text(exc)}); "
                             "damaged file?") from None
        if not isinstance(found, h5py.Dataset | h5py.Group):
            raise InputError(f"{where}: a reference to a {type(found).__name__}, not an array; damaged file?")
        return found

    def _read(self, obj, where: str) -> np.ndarray:
        """A dataset's values, its declared size (as float64) checked before reading."""
        try:
            shape = tuple(obj.shape)
        except (OSError, RuntimeError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: unreadable shape ({error_text(exc)})") from None
        check_claim(where, "the variable", shape, 8, os.path.getsize(self.path))
        try:
            return np.asarray(obj[()])
        except (OSError, RuntimeError, TypeError, ValueError) as exc:
            raise InputError(f"{where}: cannot read ({error_text(exc)})") from None


def _empty(obj) -> bool:
    """MATLAB's mark of an empty array (its dimensions stored as the data)."""
    return bool(np.any(attr_value(obj.attrs, "MATLAB_empty", f"{obj.file.filename}:{obj.name}", 0)))


def _matlab_shape(obj) -> tuple[int, ...]:
    import h5py

    if isinstance(obj, h5py.Group):
        return (1, 1)
    if _empty(obj):
        return (0, 0)
    return tuple(reversed(obj.shape))


def open_source(path: Path) -> _V5 | _V73:
    if read_head(path).startswith(MAT73_MAGIC):
        return _V73(path)
    return _V5(path)


# -- the reader ---------------------------------------------------------------------------
def _variable(value: Value, where: str, samples: str | None, keep_int: bool = False) -> Variable:
    return Variable(as_numeric(value, where, keep_int), where, samples)


def read_mat(src: _V5 | _V73, path: Path, options: DataOptions) -> Recording:
    """A .mat file → its demonstrations; see the module docstring for the options."""
    where = str(path)
    state = options.state
    if state is None or state.variable is None:
        have = ", ".join(f"{n} ({'×'.join(map(str, s))} {c})" for n, s, c in src.variables()[:8])
        raise InputError(f"{where}: data.state.variable is required for a .mat file "
                         f"(variables: {have or 'none'})")
    derive = options.derives_action
    if not derive and options.action.variable is None:
        raise InputError(f"{where}: data.action needs variable: NAME (or derive: state)")
    demos = options.demos
    unknown = demos.given() - {"variable", *CUTS} - {"per_file"}
    if unknown:
        raise InputError(f"unknown demos option(s) for a .mat file: {', '.join(sorted(unknown))} "
                         f"(use variable, {', '.join(c for c in CUTS if c != 'per_file')}, or cell arrays)")
    signal = demos.where
    if signal is not None and signal.variable is None:
        raise InputError(f"{where}: demos.where needs variable: NAME for a .mat file")
    # the variable and the samples side of each array read
    specs = {"state": (state.variable, state.samples)}
    if not derive:
        specs["action"] = (options.action.variable, options.action.samples)
    if options.time.variable is not None:
        specs["time"] = (options.time.variable, None)
    if signal is not None:
        specs["where"] = (signal.variable, signal.samples)
    for key, selection in forces.selections(options).items():  # data.force beside the state
        if selection.variable is None:
            raise InputError(f"{where}: {forces.option_path(key)} needs variable: NAME "
                             "for a .mat file")
        specs[key] = (selection.variable, selection.samples)
    values = {key: src.get(name) for key, (name, _) in specs.items()}
    cells = {key: isinstance(v, list) for key, v in values.items()}
    chunks: list[tuple[str, dict[str, np.ndarray]]] = []
    if cells["state"]:
        n_demo = len(values["state"])
        # a time variable holding one number beside cells: the sampling interval of every cell
        shared = {k for k, v in values.items() if k == "time" and not isinstance(v, list) and np.size(v) == 1}
        for key, v in values.items():
            if key in shared:
                continue
            if not isinstance(v, list) or len(v) != n_demo:
                got = f"{len(v)} cells" if isinstance(v, list) else "a matrix"
                raise InputError(f"{where}: {specs[key][0]} is {got} but "
                                 f"{state.variable} has {n_demo} cells; give each variable one "
                                 "cell per demonstration")
        if demos.variable is not None:
            raise InputError(f"{where}: demos.variable applies to matrices; {state.variable} is a "
                             "cell array (one demonstration per cell already)")
        for k in range(n_demo):
            label = f"{state.variable}{{{k + 1}}}"
            arrays = {key: _variable(v if key in shared else v[k],
                                     f"{where}: {specs[key][0]}" + ("" if key in shared else f"{{{k + 1}}}"),
                                     specs[key][1], key == "time") for key, v in values.items()}
            chunks.append((label, _oriented(arrays, f"{where}: {label}")))
    else:
        for key, v in values.items():
            if isinstance(v, list):
                raise InputError(f"{where}: {specs[key][0]} is a cell array but "
                                 f"{state.variable} is a matrix")
        arrays = {key: _variable(v, f"{where}: {specs[key][0]}", specs[key][1],
                                 key == "time") for key, v in values.items()}
        if demos.variable is not None:
            index = src.get(demos.variable)
            if isinstance(index, list):
                raise InputError(f"{where}: {demos.variable} is a cell array; a demo index is a vector")
            arrays["demo"] = _variable(index, f"{where}: {demos.variable}", None)
            if not (arrays["demo"].values.ndim == 1 or 1 in arrays["demo"].values.shape):
                raise InputError(f"{arrays['demo'].where}: a demo index must be a vector, "
                                 f"got {'×'.join(map(str, arrays['demo'].values.shape))}")
            oriented = _oriented(arrays, where)
            index_col = oriented.pop("demo")[:, 0]
            chunks = [(f"demo {label.split()[-1]}", a)
                      for label, a in split_by_index(oriented, index_col, f"{where}: {demos.variable}")]
        else:
            chunks = [(state.variable, _oriented(arrays, where))]
    passes = [signal.passes(_signal_columns(a.pop("where"), signal, where)) for _, a in chunks] \
        if signal is not None else None
    parts, state_names, action_names, origin, time_used = named_parts(
        chunks, options, where, {k: name for k, (name, _) in specs.items()}, {}, derive)
    parts = cut_parts(parts, demos, where, passes)
    time = options.time.variable
    meta = {"source": where, "format": "mat",
            "mat_version": "7.3" if isinstance(src, _V73) else "5",
            "variables": {k: name for k, (name, _) in specs.items()},
            "time": f"{time}: {time_used}" if time else time_used}
    return Recording(assemble(parts, options, where, state_names, action_names, meta), origin)


def _oriented(arrays: dict[str, Variable], where: str) -> dict[str, np.ndarray]:
    """:func:`orient`, where a time variable holding one number is the sampling interval (s, or
    ``time.unit``) of its demonstration: t = k · dt."""
    time = arrays.get("time")
    if time is None or time.values.size != 1:
        return orient(arrays, None, where)
    dt = float(time.values.ravel()[0])
    if not (np.isfinite(dt) and dt > 0):
        raise InputError(f"{time.where}: a sampling interval must be a positive number, got {dt!r}")
    out = orient({k: v for k, v in arrays.items() if k != "time"}, None, where)
    out["time"] = (np.arange(len(out["state"])) * dt)[:, None]
    return out


def _signal_columns(values: np.ndarray, signal: SignalOptions, where: str) -> np.ndarray:
    """The ``columns`` (0-based indices) of a ``demos.where`` variable, or all of it."""
    picks = signal.selection().columns
    if not picks:
        return values
    if not all(isinstance(c, int) and 0 <= c < values.shape[1] for c in picks):
        raise InputError(f"{where}: demos.where columns must be indices in 0..{values.shape[1] - 1}, "
                         f"got {picks}")
    return values[:, picks]


class MatReader(ReaderBase):
    """A MATLAB .mat recording (v7.3: the HDF5 file stays open between open and close)."""

    format = "mat"

    def __init__(self, path: str | Path, options: DataOptions) -> None:
        super().__init__(path, options)
        self._source: _V5 | _V73 | None = None

    def open(self) -> None:
        if self._source is None:
            self._source = open_source(self.path)

    def close(self) -> None:
        if isinstance(self._source, _V73):
            self._source.close()
        self._source = None

    def read(self) -> Recording:
        with self:
            return read_mat(self._source, self.path, self.options)

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        """The variables (v7.3: the HDF5 tree in MATLAB's orientation) and, with a state
        variable in the options, what would be read."""
        head = read_head(self.path)
        out: dict[str, Any] = {"tree": list_v5(self.path) if head.startswith(MAT5_MAGIC) else
                               list_v73(self.path) if head.startswith(MAT73_MAGIC) else
                               list_hdf5(self.path)}
        if self.options.state is not None and self.options.state.variable is not None:
            out.update(summary(self.read().data))
        return out


def list_v5(path: Path) -> list[dict[str, Any]]:
    """Entries ``{path, kind, shape, class}`` of a v5 file: its variables, and the fields
    and cells of its structs and cell arrays (first levels only)."""
    src = _V5(path)
    out: list[dict[str, Any]] = []
    for name, shape, cls in src.variables():
        out.append({"path": name, "kind": "variable", "shape": list(shape), "class": cls})
        if cls in NUMERIC_CLASSES and int(np.prod(shape)) == 1:  # one number: e.g. dt, a sampling interval
            out[-1]["value"] = float(np.asarray(src.load(name), dtype=float).ravel()[0])
        if cls in CONTAINERS:
            out += _v5_children(src.load(name), name)
    return truncate(out)


def _v5_children(value: Any, at: str, depth: int = 0) -> list[dict[str, Any]]:
    """Fields of structs and elements of cells (first levels only)."""
    arr = np.asarray(value)
    out: list[dict[str, Any]] = []
    if depth > 3:
        return out
    if arr.dtype.names and arr.size == 1:
        rec = arr.ravel()[0]
        for field in arr.dtype.names:
            child = np.asarray(rec[field])
            out.append({"path": f"{at}.{field}", "kind": "field", "shape": list(child.shape),
                        "class": _v5_class(child)})
            out += _v5_children(child, f"{at}.{field}", depth + 1)
    elif arr.dtype == object and not arr.dtype.names:
        for k, cell in enumerate(arr.ravel(order="F")[:20]):
            child = np.asarray(cell)
            out.append({"path": f"{at}{{{k + 1}}}", "kind": "cell", "shape": list(child.shape),
                        "class": _v5_class(child)})
            out += _v5_children(child, f"{at}{{{k + 1}}}", depth + 1)
    return out


def list_v73(path: Path) -> list[dict[str, Any]]:
    """The HDF5 tree of a v7.3 file (:func:`list_hdf5`, MATLAB's orientation) and what its cell
    arrays hold — each cell (first 20) and, for a struct in a cell, its fields with shapes."""
    import h5py

    out = list_hdf5(path, matlab=True)
    src = _V73(path)
    try:
        cells: list[tuple[str, Any]] = []
        src.f.visititems(lambda name, obj: cells.append((name, obj)) if not name.startswith("#") and
                         isinstance(obj, h5py.Dataset) and _cls(obj) == "cell" else None)
        for name, obj in cells:
            for k, ref in enumerate(src._read(obj, f"{path}: {name}").ravel()[:20]):
                child, at = src._deref(ref, f"{path}: {name}"), f"{name}{{{k + 1}}}"
                out.append({"path": at, "kind": "cell", "shape": list(_matlab_shape(child)),
                            "class": _cls(child)})
                if isinstance(child, h5py.Group):
                    out += [{"path": f"{at}.{field}", "kind": "field",
                             "shape": list(_matlab_shape(child[field])), "class": _cls(child[field])}
                            for field in child if not field.startswith("#")]
    finally:
        src.close()
    return truncate(out)


def _v5_class(arr: np.ndarray) -> str:
    from scipy.io.matlab import MatlabFunction, MatlabObject, MatlabOpaque

    if isinstance(arr, MatlabObject | MatlabFunction | MatlabOpaque):
        return "object"
    if arr.dtype.names:
        return "struct"
    if arr.dtype == object:
        return "cell"
    if arr.dtype.kind in "SU":
        return "char"
    return {"f": "double" if arr.dtype.itemsize == 8 else "single", "b": "logical"}.get(
        arr.dtype.kind, str(arr.dtype))
