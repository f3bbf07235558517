"""YAML read safely: configs, batch manifests, ROS 2 bag metadata.

:func:`read_yaml` parses one document with PyYAML's safe loader, YAML 1.2 booleans (only
true/false, so a key such as ``on`` stays a string) and bounds on what a document may
cost: its size, its nesting depth and its number of nodes once every alias is expanded
(an alias bomb is refused before anything walks it). Every failure is one line naming
the file and, where known, the line.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Any

import yaml

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io.limits import open_regular

#: limits of a YAML document (configs, manifests): nesting depth, nodes after expanding
#: aliases (billion laughs), and size of the file
MAX_DEPTH = 64
MAX_NODES = 100_000
MAX_BYTES = 16 << 20


class _Loader(yaml.SafeLoader):
    """SafeLoader with YAML 1.2 booleans (only true/false, so keys like ``on`` stay
    strings), bounded nesting depth and a budget of nodes counted with every alias
    expanded (so an alias bomb is refused before anything walks it)."""

    def __init__(self, stream: str) -> None:
        super().__init__(stream)
        self._depth = 0

    def compose_node(self, parent, index):  # noqa: ANN001, ANN201 - PyYAML's signature
        self._depth += 1
        if self._depth > MAX_DEPTH:
            mark = self.peek_event().start_mark
            raise yaml.composer.ComposerError(None, None, f"nested deeper than {MAX_DEPTH} levels", mark)
        try:
            return super().compose_node(parent, index)
        finally:
            self._depth -= 1


_Loader.yaml_implicit_resolvers = {
    first: [(tag, regexp) for tag, regexp in resolvers if tag != "tag:yaml.org,2002:bool"]
    for first, resolvers in yaml.SafeLoader.yaml_implicit_resolvers.items()
}
_Loader.add_implicit_resolver("tag:yaml.org,2002:bool", re.compile(r"^(?:true|True|TRUE|"
                              r"false|False|FALSE)$"), list("tTfF"))


def _expanded_size(root: yaml.Node) -> int | None:
    """Number of nodes of ``root`` with every alias expanded (shared nodes counted at each
    use), computed once per distinct node; None if an alias refers to its own ancestor."""
    size: dict[int, int] = {}
    stack: list[tuple[yaml.Node, bool]] = [(root, False)]
    open_: set[int] = set()
    while stack:
        node, done = stack.pop()
        key = id(node)
        children = [n for pair in node.value for n in pair] if isinstance(node, yaml.MappingNode) else \
            list(node.value) if isinstance(node, yaml.SequenceNode) else []
        if done:
            size[key] = min(1 + sum(size[id(c)] for c in children), 1 << 62)
            open_.discard(key)
            continue
        if key in size:
            continue
        if key in open_:
            return None
        open_.add(key)
        stack.append((node, True))
        for child in children:
            if id(child) in open_:
                return None
            if id(child) not in size:
                stack.append((child, False))
    return size[id(root)]


def read_yaml(path: str | Path, what: str = "config", error: type = ConfigError
              ) -> tuple[Any, yaml.Node | None]:
    """Parse one YAML document safely → (data, composed node).

    Refused with a one-line ``error`` naming the file (and line, or byte offset): files
    over ``MAX_BYTES``, bytes that are not UTF-8, YAML errors, nesting deeper than
    ``MAX_DEPTH`` and more than ``MAX_NODES`` nodes once aliases are expanded.
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
        loader = _Loader(text)
        node = loader.get_single_node()
        if node is not None:
            total = _expanded_size(node)
            if total is None:
                raise error(f"{path}:{node.start_mark.line + 1}: invalid YAML (an alias refers to "
                            "its own parent)")
            if total > MAX_NODES:
                raise error(f"{path}: {what} has {total} values once aliases are expanded "
                            f"(limit {MAX_NODES}); refused")
        data = loader.construct_document(node) if node is not None else None
    except yaml.YAMLError as exc:
        mark = getattr(exc, "problem_mark", None)
        where = f"{path}:{mark.line + 1}" if mark else str(path)
        problem = getattr(exc, "problem", None) or str(exc).splitlines()[0]
        raise error(f"{where}: invalid YAML ({problem})") from None
    finally:
        if loader is not None:
            loader.dispose()
    return data, node
