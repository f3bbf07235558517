"""``ccl simulate PROBLEM --set NAME=VALUE``: any keyword of a problem's function from the
command line (the compliance of a hinge, the tremor of a hand, a range as ``[60, 120]``)."""

from __future__ import annotations

from typing import Any

from ccl_cli.errors import InputError

#: Longest VALUE read (a number, a short list or a word).
MAX_VALUE = 200


def parse_settings(items: list[str] | None) -> dict[str, Any]:
    """{NAME: VALUE} of ``NAME=VALUE`` items, each VALUE read as YAML (``0.003`` a number,
    ``[60, 120]`` a list, ``filtered`` a word): one InputError for the first malformed item."""
    import yaml

    out: dict[str, Any] = {}
    for item in items or []:
        name, eq, text = item.partition("=")
        name = name.strip().replace("-", "_")
        if not eq or not name.isidentifier() or len(text) > MAX_VALUE:
            raise InputError(f"--set takes NAME=VALUE (a keyword of the problem and a number, a word or a "
                             f"list such as [60, 120]), got {item[:80]!r}")
        try:
            value = yaml.safe_load(text)
        except yaml.YAMLError:
            raise InputError(f"--set {name}: cannot read {text[:80]!r} (a number, a word or a list such as "
                             "[60, 120])") from None
        if not isinstance(value, int | float | str | bool | list) or (
                isinstance(value, list) and not all(isinstance(v, int | float) for v in value)):
            raise InputError(f"--set {name}: {text[:80]!r} is not a number, a word or a list of numbers")
        if name in out:
            raise InputError(f"--set {name} is given twice")
        out[name] = tuple(value) if isinstance(value, list) else value
    return out
