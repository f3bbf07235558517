"""What an HDF5 or .mat file holds: one entry per group, dataset, link or variable.

Used by ``ccl inspect`` and by error messages that list a file's contents. Links are
described, never followed; MATLAB v7.3 arrays are shown in MATLAB's orientation with
their ``MATLAB_class``, and its ``#refs#`` storage is hidden.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io import h5safe

LIMIT = 500


def describe_tree(path: str | Path, limit: int = LIMIT) -> list[dict[str, Any]]:
    """Entries ``{path, kind, shape, dtype, class?, attrs?}`` of an HDF5 or .mat file
    (``kind``: group, dataset, soft link, external link, variable); at most ``limit``
    entries (a last entry ``{kind: "truncated", count}`` says how many were left out)."""
    from ccl_cli.io.matfile import V5_MAGIC, V73_MAGIC, read_header

    path = Path(path)
    head = read_header(path)
    if head.startswith(V5_MAGIC):
        entries = _mat_v5(path)
    else:
        entries = _hdf5(path, matlab=head.startswith(V73_MAGIC))
    if len(entries) > limit:
        entries = [*entries[:limit], {"kind": "truncated", "count": len(entries) - limit}]
    return entries


def _hdf5(path: Path, matlab: bool) -> list[dict[str, Any]]:
    """The listing; links are described, not followed, so a file with an external link is
    listed (and its entry says so) after the time-limited probe of :mod:`h5safe`."""
    import h5py

    if not h5safe.sealed(path):
        h5safe.probe(path)
    try:
        f = h5py.File(path, "r")
    except OSError as exc:
        raise InputError(f"{path}: cannot open as HDF5 ({exc})") from None
    out: list[dict[str, Any]] = []
    with f:
        def visit(name: str, link) -> None:
            if matlab and name.startswith("#"):
                return
            entry: dict[str, Any] = {"path": name}
            if isinstance(link, h5py.ExternalLink):
                entry.update(kind="external link", target=f"{link.filename}:{link.path}")
            elif isinstance(link, h5py.SoftLink):
                entry.update(kind="soft link", target=link.path)
            else:
                obj = f[name]
                if isinstance(obj, h5py.Group):
                    entry["kind"] = "group"
                else:
                    shape = tuple(obj.shape)
                    entry.update(kind="dataset", shape=list(reversed(shape)) if matlab else list(shape),
                                 dtype=str(obj.dtype) if obj.dtype != h5py.ref_dtype else "reference")
                    if obj.is_virtual:
                        entry["virtual"] = True
                names = obj.attrs.get("names", obj.attrs.get("column_names"))
                if names is not None:
                    entry["names"] = [v.decode() if isinstance(v, bytes) else str(v) for v in np.ravel(names)]
                cls = obj.attrs.get("MATLAB_class")
                if cls is not None:
                    entry["class"] = cls.decode() if isinstance(cls, bytes) else str(cls)
            out.append(entry)

        try:
            f.visititems_links(visit)
        except (OSError, RuntimeError, KeyError) as exc:
            raise InputError(f"{path}: cannot read the HDF5 structure ({exc})") from None
    return out


def _mat_v5(path: Path) -> list[dict[str, Any]]:
    from ccl_cli.io.matfile import _V5, CONTAINERS

    src = _V5(path)
    out: list[dict[str, Any]] = []
    for name, shape, cls in src.variables():
        out.append({"path": name, "kind": "variable", "shape": list(shape), "class": cls})
        if cls in CONTAINERS:
            out += _v5_children(src._load(name), name)
    return out


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
    return out


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
