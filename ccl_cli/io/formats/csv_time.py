"""Exact time stamps from the text of a CSV column.

Integer nanoseconds stay int64; decimal seconds are split at the point, never passed
through float64 (epoch nanoseconds need 61 bits). The column comes as strings or as a
NumPy text array (``S``: ASCII bytes, one byte a character, as the streaming reader keeps
it; or ``U``). The common cases — all integers, or integers and plain decimals — are
parsed at array speed (:func:`_time_ns_vectorised`); anything else value by value, naming
the row at fault (:func:`_time_ns_per_value`).
"""

from __future__ import annotations

import math
import re
from collections.abc import Sequence

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.options import UNIT_NS

_INT = re.compile(r"^[+-]?\d+$")
_DEC = re.compile(r"^([+-]?)(\d*)\.(\d*)$")
_I64 = 2**63 - 1
#: an integer stamp of more digits is out of range whatever its unit (int() refuses > 4,300)
MAX_DIGITS = 30


def parse_time_ns(column: Sequence[str] | np.ndarray, unit: str | None, where: str) -> np.ndarray:
    """Exact int64 nanoseconds from text (n,) → (n,). ``unit`` None: integers ≥ 1e15 are
    ns, everything else seconds. Values that are not finite or do not fit int64 ns are an
    :class:`InputError` naming the row."""
    fast = _time_ns_vectorised(column, unit)
    return fast if fast is not None else _time_ns_per_value(_strings(column), unit, where)


def _strings(column: Sequence[str] | np.ndarray) -> Sequence[str]:
    if isinstance(column, np.ndarray):
        if column.dtype.kind == "S":
            return [v.decode("ascii") for v in column.tolist()]
        return [str(v) for v in column.tolist()]
    return column


def _as_text(column: Sequence[str] | np.ndarray) -> np.ndarray:
    if isinstance(column, np.ndarray) and column.dtype.kind in "SU":
        return column
    return np.array(list(column), dtype=str)


def _digits(values: np.ndarray) -> np.ndarray:
    """Where each non-empty entry is all decimal digits (``\\d+``)."""
    test = np.char.isdigit if values.dtype.kind == "S" else np.char.isdecimal  # bytes: ASCII digits
    return test(values) & (np.char.str_len(values) > 0)


def _time_ns_vectorised(column: Sequence[str] | np.ndarray, unit: str | None) -> np.ndarray | None:
    """The common cases at array speed: all integers, or integers and plain decimals
    (``[+-]digits.digits``). None when a value is anything else or out of range (then
    :func:`_time_ns_per_value` parses it, and names the row at fault)."""
    if isinstance(column, np.ndarray) and column.dtype.kind in "iu":
        return _integers(column.astype(np.int64, copy=False), unit)
    values = _as_text(column)
    if values.size == 0:
        return None
    b = values.dtype.kind == "S"
    plus, minus, dot = (b"+", b"-", b".") if b else ("+", "-", ".")
    negative = np.char.startswith(values, minus)
    signed = negative | np.char.startswith(values, plus)
    body = np.where(signed, np.char.lstrip(values, plus + minus), values)
    if not (np.char.str_len(body) == np.char.str_len(values) - signed).all():
        return None  # more than one sign
    if int(np.char.str_len(body).max()) > MAX_DIGITS + 1 + 12:
        return None  # a value beyond any range: named by the per-value parse
    try:
        if _digits(body).all():
            return _integers(values.astype(np.int64), unit)
        whole, point, frac = np.char.partition(body, dot).T
        empty_whole, empty_frac = np.char.str_len(whole) == 0, np.char.str_len(frac) == 0
        decimal = (point == dot) & (empty_whole | _digits(whole)) & (empty_frac | _digits(frac))
        if not (decimal | ((point != dot) & _digits(whole))).all():
            return None
        scale = UNIT_NS[unit or "s"]
        n_digits = len(str(scale)) - 1
        zero = b"0" if b else "0"
        whole = np.where(empty_whole, zero, whole).astype(np.int64)
        if int(whole.max(initial=0)) >= _I64 // scale:
            return None
        ns = whole * scale
        if n_digits:
            kind = "S" if b else "U"
            ns += np.char.ljust(frac, n_digits, zero).astype(f"{kind}{n_digits}").astype(np.int64)
        return np.where(negative, -ns, ns)
    except (ValueError, OverflowError):
        return None


def _integers(ints: np.ndarray, unit: str | None) -> np.ndarray | None:
    """Integer stamps (n,) int64 in ``unit`` (None: ns from 1e15 on, else s) as ns; None when
    one does not fit int64 ns."""
    if not ints.size:
        return None
    big = max(abs(int(ints.min())), abs(int(ints.max())))
    unit = unit or ("ns" if big >= 10**15 else "s")
    if big * UNIT_NS[unit] > _I64:
        return None
    return ints * UNIT_NS[unit]


def _ns(value: int, v: str, i: int, where: str) -> int:
    if not -_I64 <= value <= _I64:
        raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is out of range "
                         "(beyond ±9.2e18 ns)")
    return value


def _int(text: str, v: str, i: int, where: str) -> int:
    """``int(text)`` of a ``[+-]?\\d+`` text, refused as out of range past :data:`MAX_DIGITS`
    digits (before Python's own 4,300-digit limit could raise)."""
    if len(text.lstrip("+-")) > MAX_DIGITS:
        raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is out of range "
                         f"(an integer of {len(text.lstrip('+-'))} digits)")
    return int(text)


def _time_ns_per_value(column: Sequence[str], unit: str | None, where: str) -> np.ndarray:
    """:func:`parse_time_ns` one value at a time (any float syntax; exact errors)."""
    if all(_INT.match(v.strip()) for v in column):  # str.strip: any Unicode space around it
        ints = [_int(v.strip(), v, i, where) for i, v in enumerate(column)]
        if unit is None:
            unit = "ns" if max(map(abs, ints), default=0) >= 10**15 else "s"
        scale = UNIT_NS[unit]
        return np.array([_ns(x * scale, v, i, where)
                         for i, (x, v) in enumerate(zip(ints, column, strict=True))], dtype=np.int64)
    _check_values(column, unit, where)
    scale = UNIT_NS[unit or "s"]
    digits = len(str(scale)) - 1
    out = np.empty(len(column), dtype=np.int64)
    for i, v in enumerate(column):  # exact decimal split; a float would lose ns at epoch scale
        m = _DEC.match(v.strip())
        if m:
            sign = -1 if m.group(1) == "-" else 1
            whole = _int(m.group(2) or "0", v, i, where)
            frac = (m.group(3) + "0" * digits)[:digits] if digits else ""
            out[i] = _ns(sign * (whole * scale + (int(frac) if frac else 0)), v, i, where)
        elif _INT.match(v.strip()):
            out[i] = _ns(_int(v.strip(), v, i, where) * scale, v, i, where)
        else:
            try:
                value = float(v) * scale
            except ValueError:
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not a number") from None
            if not math.isfinite(value):
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not finite")
            out[i] = _ns(int(round(value)), v, i, where)
    return out


def _check_values(column: Sequence[str], unit: str | None, where: str) -> None:
    """Before any value is scaled: the first value that is not a finite number, then (``unit``
    None) integer nanoseconds (≥ 1e15) beside values that are not integers, each one line
    naming the rows — not a range error on a valid stamp scaled as seconds."""
    big = other = None
    for i, v in enumerate(column):
        s = v.strip()
        if _INT.match(s):
            digits = s.lstrip("+-")
            if big is None and (len(digits) > MAX_DIGITS or abs(int(digits)) >= 10**15):
                big = i
            continue
        if not _DEC.match(s):
            try:
                value = float(v)
            except ValueError:
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not a number") from None
            if not math.isfinite(value):
                raise InputError(f"{where}: time value {v[:40]!r} in row {i + 2} is not finite")
        other = i if other is None else other
    if unit is None and big is not None and other is not None:
        raise InputError(f"{where}: time column mixes integer nanoseconds ({column[big][:40]!r}, row "
                         f"{big + 2}) with other values ({column[other][:40]!r}, row {other + 2}); "
                         "set time.unit")
