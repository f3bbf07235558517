"""Typed, checked reads of HDF5 attributes and datasets.

Each accessor turns one attribute or dataset of an open ``h5py`` object into a checked
Python or NumPy value, or raises one :class:`~ccl_cli.errors.InputError` line naming the
file (``where``) and the object: missing, of the wrong type or shape, unreadable (a
damaged file), not finite, or claiming more bytes than the file could hold or the cap
allows (:mod:`ccl_cli.io.limits`).
Datasets are read through h5py's low-level API (``H5Dread`` into a float64 buffer), which
converts while reading; ``docs/readers.md`` has the measurements behind that choice.
"""

from __future__ import annotations

import functools
import os
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.limits import check_claim

_MISSING = object()


def error_text(exc: BaseException) -> str:
    """'TypeName: first line of the message' of a library exception."""
    text = str(exc).splitlines()[0] if str(exc) else ""
    return f"{type(exc).__name__}: {text}" if text else type(exc).__name__


def _attr(attrs, key: str, where: str, default: Any) -> Any:
    try:
        present = key in attrs
        value = attrs[key] if present else default
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:  # h5py's, never ours
        raise InputError(f"{where}: attribute {key!r} cannot be read ({error_text(exc)})") from None
    if value is _MISSING:
        raise InputError(f"{where}: attribute {key!r} is missing")
    return value


def _describe(value: Any) -> str:
    if isinstance(value, np.ndarray):
        return f"an array {value.dtype} {value.shape}"
    return f"{type(value).__name__} {value!r}"[:80]


def _as_str(value: Any) -> str | None:
    if isinstance(value, bytes | np.bytes_):
        try:
            return bytes(value).decode("utf-8")
        except UnicodeDecodeError:
            return None
    if isinstance(value, str):  # h5py decodes invalid UTF-8 with surrogate escapes: refused too
        try:
            value.encode("utf-8")
        except UnicodeEncodeError:
            return None
        return str(value)
    return None


def attr_value(attrs, key: str, where: str, default: Any = _MISSING) -> Any:
    """An attribute as h5py reads it, unchecked (a damaged one is an InputError)."""
    return _attr(attrs, key, where, default)


def attr_str(attrs, key: str, where: str, default: Any = _MISSING) -> str:
    """A scalar string attribute (str or UTF-8 bytes)."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    text = _as_str(value)
    if text is None:
        raise InputError(f"{where}: attribute {key!r} must be a string, got {_describe(value)}")
    return text


def attr_int(attrs, key: str, where: str, default: Any = _MISSING) -> int:
    """A scalar integer attribute (not a bool, float or string)."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    if isinstance(value, int | np.integer) and not isinstance(value, bool | np.bool_):
        return int(value)
    raise InputError(f"{where}: attribute {key!r} must be an integer, got {_describe(value)}")


def attr_version(attrs, key: str, where: str) -> int:
    """A format version: an integer, or a number or text that names one ("1", "1.0", 1.0 —
    as other writers and MATLAB store it); anything else is one InputError line."""
    value = _attr(attrs, key, where, _MISSING)
    text = _as_str(value)
    if text is not None or isinstance(value, float | np.floating):
        try:
            number = float(text if text is not None else value)
        except ValueError:
            number = float("nan")
        if number.is_integer() and 0 <= number < 2**31:
            return int(number)
        raise InputError(f"{where}: attribute {key!r} must be a version number, got {_describe(value)}")
    return attr_int(attrs, key, where)


def attr_float(attrs, key: str, where: str, default: Any = _MISSING, positive: bool = False) -> float:
    """A finite scalar number attribute."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    if not isinstance(value, int | float | np.integer | np.floating) or isinstance(value, bool | np.bool_):
        raise InputError(f"{where}: attribute {key!r} must be a number, got {_describe(value)}")
    out = float(value)
    if not np.isfinite(out) or (positive and not out > 0):
        raise InputError(f"{where}: attribute {key!r} must be a finite{' positive' if positive else ''} "
                         f"number, got {out}")
    return out


def attr_json(attrs, key: str, where: str, default: Any = _MISSING, kind: type | None = None) -> Any:
    """A JSON-encoded string attribute, decoded (``kind``: the type the value must have)."""
    value = _attr(attrs, key, where, default)
    if value is default and default is not _MISSING:
        return value
    from ccl_cli.io.jsonsafe import loads

    out = loads(attr_str(attrs, key, where), f"{where}: attribute {key!r}")
    if kind is not None and not isinstance(out, kind):
        raise InputError(f"{where}: attribute {key!r} must be a JSON {kind.__name__}, got {_describe(out)}")
    return out


def attr_strings(attrs, key: str, where: str, n: int) -> list[str]:
    """A 1-D array of ``n`` strings (absent → ``n`` empty strings)."""
    value = _attr(attrs, key, where, None)
    if value is None:
        return [""] * n
    arr = np.asarray(value)
    texts = [_as_str(v) for v in arr.ravel()] if arr.ndim == 1 else None
    if texts is None or any(t is None for t in texts) or len(texts) != n:
        raise InputError(f"{where}: attribute {key!r} must be {n} strings, got {_describe(value)}")
    return texts  # type: ignore[return-value]


def attr_names(attrs, key: str, where: str) -> list[str] | None:
    """An attribute naming columns (a string or an array of them; numbers by their text),
    None when absent; undecodable bytes or other types are an InputError."""
    value = _attr(attrs, key, where, None)
    if value is None:
        return None
    out = []
    for v in np.ravel(np.asarray(value, dtype=object)):
        text = _as_str(v) if isinstance(v, bytes | str | np.bytes_) else \
            str(v) if isinstance(v, int | float | np.integer | np.floating) else None
        if text is None:
            raise InputError(f"{where}: attribute {key!r} must hold names (strings), got {_describe(value)}")
        out.append(text)
    return out


def members(group, where: str) -> list[str]:
    """Names of the members of ``group`` (a damaged group index is an InputError)."""
    try:
        return list(group)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {group.name} cannot be listed ({error_text(exc)})") from None


def has(group, name: str, where: str) -> bool:
    """``name in group``, with a damaged group an InputError."""
    try:
        return name in group
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {group.name}/{name} cannot be looked up ({error_text(exc)})") from None


def _dataset_id(group, name: str, where: str):
    """The low-level ``DatasetID`` of ``name`` under ``group`` (InputError if absent or not
    a dataset); a single link is looked up in libhdf5 directly, a path through h5py."""
    import h5py
    from h5py import h5d, h5o

    try:
        if "/" in name or name in (".", ""):  # a path: h5py's lookup walks it
            obj = group[name] if name in group else None
        else:  # one link
            raw = name.encode()
            obj = h5o.open(group.id, raw) if group.id.links.exists(raw) else None
    except (OSError, KeyError, RuntimeError, ValueError, TypeError, UnicodeEncodeError) as exc:
        raise InputError(f"{where}: {name} cannot be read ({error_text(exc)})") from None
    if obj is None:
        raise InputError(f"{where}: {name} is missing")
    if isinstance(obj, h5d.DatasetID):
        return obj
    if isinstance(obj, h5py.Dataset):
        return obj.id
    kind = type(obj).__name__ if isinstance(obj, h5py.HLObject) else type(group[name]).__name__
    raise InputError(f"{where}: {name} must be a dataset, got a {kind}")


def dataset(group, name: str, where: str):
    """The ``h5py.Dataset`` ``name`` under ``group`` (InputError if absent or a group)."""
    import h5py

    return h5py.Dataset(_dataset_id(group, name, where))


def group_of(parent, name: str, where: str, required: bool = True):
    """The ``h5py.Group`` ``name`` under ``parent`` (None if absent and not ``required``)."""
    import h5py

    try:
        obj = parent.get(name)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {name} cannot be read ({error_text(exc)})") from None
    if obj is None:
        if required:
            raise InputError(f"{where}: {name} is missing")
        return None
    if not isinstance(obj, h5py.Group):
        raise InputError(f"{where}: {name} must be a group, got a {type(obj).__name__}")
    return obj


def numeric(group, name: str, where: str, ndim: tuple[int, ...] = (1, 2), finite: bool = True,
            limit: float | None = None) -> np.ndarray:
    """A real numeric dataset as float64, of one of the dimensionalities ``ndim``.

    Checked before reading: the type (integers or floats, no strings, compounds,
    references) and the declared size (:func:`~ccl_cli.io.limits.check_claim`: the cap, and
    decompression bombs); after: finiteness (``finite``) and magnitude (``|v| <= limit``).
    """
    import h5py

    dsid = _dataset_id(group, name, where)  # the high-level Dataset only for messages
    ds = functools.partial(h5py.Dataset, dsid)  # for messages: ds().name, ds().file
    try:
        dtype, shape = dsid.dtype, tuple(dsid.shape)
    except (OSError, RuntimeError, ValueError, TypeError) as exc:  # a damaged datatype or dataspace
        raise InputError(f"{where}: {ds().name} has an unreadable type or shape "
                         f"({error_text(exc)})") from None
    if dtype.kind not in "fiu":
        raise InputError(f"{where}: {ds().name} must be numeric, got dtype {dtype}")
    if len(shape) not in ndim:
        allowed = " or ".join(f"{d}-D" for d in ndim)
        raise InputError(f"{where}: {ds().name} must be {allowed}, got shape {shape}")
    check_claim(where, ds().name, shape, 8, os.path.getsize(ds().file.filename))
    from h5py import h5s

    try:  # libhdf5 converts to float64 while reading
        value = np.empty(shape, dtype=np.float64)
        if value.size:
            dsid.read(h5s.ALL, h5s.ALL, value)
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{where}: {ds().name} cannot be read ({error_text(exc)})") from None
    if finite and not np.isfinite(value).all():
        raise InputError(f"{where}: {ds().name} contains NaN or inf")
    if limit is not None and value.size and float(np.abs(value).max()) > limit:
        raise InputError(f"{where}: {ds().name} holds values beyond ±{limit:g} (max |v| = "
                         f"{np.abs(value).max():.3g}); no fit produces them and predictions would overflow")
    return value


def strings(group, name: str, where: str) -> list[str]:
    """A 1-D dataset of strings."""
    ds = dataset(group, name, where)
    label = f"{where}: {ds.name}"
    if ds.ndim != 1 or ds.dtype.kind not in "OSU":
        raise InputError(f"{label} must be a 1-D array of strings, got {ds.dtype} {ds.shape}")
    check_claim(where, ds.name, ds.shape, max(ds.dtype.itemsize, 64), os.path.getsize(ds.file.filename))
    try:
        raw = ds[()]
    except (OSError, KeyError, RuntimeError, ValueError, TypeError) as exc:
        raise InputError(f"{label} cannot be read ({error_text(exc)})") from None
    texts = [_as_str(v) for v in raw]
    if any(t is None for t in texts):
        raise InputError(f"{label} must hold strings")
    return texts  # type: ignore[return-value]
