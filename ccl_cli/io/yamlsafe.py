"""YAML read safely: configs, batch manifests, ROS 2 bag metadata.

:func:`read_yaml` reads one document in two passes. First the parser's events alone are
walked (:func:`scan`: libyaml's parser where PyYAML has it, nothing composed or
constructed), and the document is refused as soon as it passes a bound: its size in bytes
(before any parsing), its nesting depth, its number of nodes with every alias expanded
(a key bomb or an alias bomb stops at the first node over the limit), an integer wider than
64 bits (no field takes one; Python would refuse to convert one of over 4,300 digits) and a
key given twice in one mapping (both lines named). Then it is composed and constructed with
PyYAML's safe loader and YAML 1.2 booleans (only true/false, so a key such as ``on`` stays
a string). Every failure is one line naming the file and, where known, the line and key.
"""

from __future__ import annotations

import re
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

import yaml

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io.limits import open_regular

#: limits of a YAML document (configs, manifests, bag metadata): nesting depth, nodes after
#: expanding aliases (billion laughs, key bombs), and size of the file
MAX_DEPTH = 64
MAX_NODES = 100_000
MAX_BYTES = 16 << 20
#: the widest integer any field takes (uint64), and its number of digits
MAX_INT = (1 << 64) - 1
INT_TAG = "tag:yaml.org,2002:int"

_C = getattr(yaml, "CSafeLoader", None)  # libyaml's parser, where PyYAML was built with it


def _yaml12(cls: type) -> type:
    """``cls`` with YAML 1.2 booleans: only true/false (any case), so ``on``/``yes`` stay strings."""
    cls.yaml_implicit_resolvers = {
        first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:bool"]
        for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
    }
    cls.add_implicit_resolver("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|false|False|FALSE)$"),
                              list("tTfF"))
    return cls


@_yaml12
class _Loader(_C or yaml.SafeLoader):  # type: ignore[misc, valid-type]
    """The safe loader (libyaml's where available) with YAML 1.2 booleans."""


@dataclass
class _Open:
    """A mapping or sequence being read: where it starts, its node count then, its anchor,
    and (a mapping) the line of each key so far, the current key and whether a key is next."""

    mapping: bool
    start: int
    anchor: str | None
    keys: dict[tuple[str, bool], int] = field(default_factory=dict)
    key: Any = None
    expect_key: bool = True
    index: int = 0


class _Refused(Exception):
    """A bound passed at ``line`` (1-based; 0: unknown)."""

    def __init__(self, line: int, message: str) -> None:
        super().__init__(message)
        self.line, self.message = line, message


def _key_path(stack: list[_Open]) -> str:
    """The dotted key of the node being read: ``data.state.columns[2]``."""
    parts = []
    for node in stack:
        if node.mapping:
            parts.append("." + (str(node.key) if node.key is not None else "?"))
        else:
            parts.append(f"[{node.index}]")
    return "".join(parts).lstrip(".") or "the document"


def scan(text: str, what: str = "config") -> None:
    """Walk the parser's events of ``text`` and refuse (:class:`_Refused`) the first node past
    a bound: nesting over :data:`MAX_DEPTH`, more than :data:`MAX_NODES` nodes with aliases
    expanded, an alias to its own ancestor, an integer beyond 64 bits, a duplicate key.
    Nothing is composed; YAML syntax errors are left to the loader (raised there)."""
    parser = _Loader(text)
    resolver = _Loader.resolve
    stack: list[_Open] = []
    anchors: dict[str, int] = {}
    count = 0
    try:
        while True:
            event = parser.get_event()
            if event is None or isinstance(event, yaml.StreamEndEvent):
                return
            if isinstance(event, yaml.CollectionEndEvent):
                done = stack.pop()
                if done.anchor is not None:
                    anchors[done.anchor] = count - done.start
                _completed(stack)
                continue
            if not isinstance(event, yaml.NodeEvent):
                continue
            line = event.start_mark.line + 1 if event.start_mark is not None else 0
            parent = stack[-1] if stack else None
            is_key = parent is not None and parent.mapping and parent.expect_key
            if isinstance(event, yaml.AliasEvent):
                if any(o.anchor == event.anchor for o in stack):
                    raise _Refused(line, "invalid YAML (an alias refers to its own parent)")
                count += anchors.get(event.anchor, 1)
            else:
                count += 1
            if count > MAX_NODES:
                raise _Refused(line, f"{what} has more than {MAX_NODES} values once aliases are expanded "
                                     "(a key or alias bomb?); refused before building it")
            if isinstance(event, yaml.ScalarEvent):
                plain = bool(event.implicit[0]) and not event.style
                if plain and len(event.value) > 19 and resolver(parser, yaml.ScalarNode, event.value,
                                                                (True, False)) == INT_TAG:
                    _check_int(parser, event.value, _key_path(stack) if not is_key else "a key", line)
                if event.anchor is not None:
                    anchors[event.anchor] = 1
                if is_key:
                    ident = (event.value, plain)
                    if ident in parent.keys and event.value != "<<":
                        inside = f"in {_key_path(stack[:-1])}" if len(stack) > 1 else "at the top level"
                        raise _Refused(line, f"duplicate key {event.value[:80]!r} {inside} (lines "
                                             f"{parent.keys[ident]} and {line}); give each key once")
                    parent.keys[ident] = line
                    parent.key = event.value[:80]
                _completed(stack)
            elif isinstance(event, yaml.CollectionStartEvent):
                if is_key:
                    parent.key = "?"
                if len(stack) >= MAX_DEPTH:
                    raise _Refused(line, f"invalid YAML (nested deeper than {MAX_DEPTH} levels)")
                stack.append(_Open(isinstance(event, yaml.MappingStartEvent), count - 1, event.anchor))
            else:  # an alias
                _completed(stack)
    finally:
        parser.dispose()


def _completed(stack: list[_Open]) -> None:
    """A node of the innermost collection is complete: a mapping's key or value, or an item."""
    if stack:
        top = stack[-1]
        if top.mapping:
            top.expect_key = not top.expect_key
        else:
            top.index += 1


def _check_int(loader: Any, text: str, key: str, line: int) -> None:
    """Refuse a plain integer scalar wider than 64 bits (before anything converts one of
    thousands of digits; the loader's own conversion for the others)."""
    digits = len(text.lstrip("+-").replace("_", ""))
    value = None
    if digits <= 40:
        try:
            value = loader.construct_yaml_int(yaml.ScalarNode(INT_TAG, text))
        except (ValueError, TypeError):
            value = None
    if value is None or abs(value) > MAX_INT:
        raise _Refused(line, f"{key} is an integer of {digits} digits, beyond 64 bits (no field takes it)")


def read_yaml(path: str | Path, what: str = "config", error: type = ConfigError
              ) -> tuple[Any, yaml.Node | None]:
    """Parse one YAML document safely → (data, composed node).

    Refused with a one-line ``error`` naming the file (and line, and key where it helps):
    files over :data:`MAX_BYTES` (before parsing), bytes that are not UTF-8, then — while
    only the parser's events are walked (:func:`scan`) — nesting deeper than
    :data:`MAX_DEPTH`, more than :data:`MAX_NODES` nodes once aliases are expanded,
    integers beyond 64 bits and duplicate keys; YAML errors.
    """
    path = Path(path)
    try:
        with open_regular(path, f"the {what}") as f:
            raw = f.read(MAX_BYTES + 1)
    except InputError as exc:  # a FIFO or device: refused before it could block
        raise error(exc.message) from None
    except OSError as exc:
        raise error(f"{path}: cannot read {what} ({exc.strerror})") from None
    if len(raw) > MAX_BYTES:
        raise error(f"{path}: {what} is larger than {MAX_BYTES >> 20} MB")
    try:
        text = raw.decode("utf-8-sig")
    except UnicodeDecodeError as exc:
        raise error(f"{path}: {what} is not UTF-8 text (byte {exc.start}: 0x{raw[exc.start]:02x})") from None
    loader = None
    try:
        scan(text, what)
        loader = _Loader(text)
        node = loader.get_single_node()
        data = loader.construct_document(node) if node is not None else None
    except _Refused as exc:
        where = f"{path}:{exc.line}" if exc.line else str(path)
        raise error(f"{where}: {exc.message}") from None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        if "maximum nesting depth" in problem:  # libyaml's own bound, met while scanning ahead
            problem = f"nested deeper than {MAX_DEPTH} levels"
        raise error(f"{where}: invalid YAML ({problem})") from None
    finally:
        if loader is not None:
            loader.dispose()
    return data, node
