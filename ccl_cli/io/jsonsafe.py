"""JSON text read safely (model attributes, a batch job's record): integers bounded while
parsing, nesting bounded, every failure one line.

Python refuses to convert an integer of more than 4,300 digits (a ``ValueError`` deep
inside ``json``), and no field ccl reads takes one wider than 64 bits: such an integer is
kept aside while parsing (never converted) and then refused, naming the key and line.

A leaf: it imports only :mod:`ccl_cli.errors`.
"""

from __future__ import annotations

import json
from typing import Any

from ccl_cli.errors import InputError

#: the widest integer any field takes (uint64)
MAX_INT = (1 << 64) - 1


class _Wide:
    """An integer literal too wide to convert: its text."""

    def __init__(self, text: str) -> None:
        self.text = text


def _parse_int(text: str) -> int | _Wide:
    if len(text) > 21:  # longer than any 64-bit value with its sign
        return _Wide(text)
    value = int(text)
    return value if abs(value) <= MAX_INT else _Wide(text)


def _find_wide(value: Any, path: str = "") -> tuple[str, _Wide] | None:
    """The first wide integer of a decoded value, with its key path (``a.b[2]``)."""
    stack = [(value, path)]
    while stack:
        item, where = stack.pop()
        if isinstance(item, _Wide):
            return where or "the value", item
        if isinstance(item, dict):
            stack += [(v, f"{where}.{k}" if where else str(k)) for k, v in reversed(item.items())]
        elif isinstance(item, list):
            stack += [(v, f"{where}[{i}]") for i, v in reversed(list(enumerate(item)))]
    return None


def loads(text: str | bytes, where: str) -> Any:
    """``json.loads(text)``, or one :class:`InputError` naming ``where``: not JSON, nested
    past the interpreter's recursion limit, or holding an integer beyond 64 bits (with its
    key and line)."""
    wide: list[str] = []

    def parse_int(digits: str) -> int | _Wide:
        out = _parse_int(digits)
        if isinstance(out, _Wide):
            wide.append(digits)
        return out

    try:
        value = json.loads(text, parse_int=parse_int)
    except (json.JSONDecodeError, RecursionError, UnicodeDecodeError) as exc:
        first = str(exc).splitlines()[0] if str(exc) else type(exc).__name__
        raise InputError(f"{where} is not valid JSON ({type(exc).__name__}: {first})") from None
    if wide:
        key, item = _find_wide(value) or ("a value", _Wide(wide[0]))
        body = text.decode("utf-8", "replace") if isinstance(text, bytes) else text
        line = body.count("\n", 0, max(body.find(item.text), 0)) + 1
        raise InputError(f"{where} line {line}: {key} is an integer of {len(item.text.lstrip('-'))} digits, "
                         "beyond 64 bits (no field takes it)")
    return value
