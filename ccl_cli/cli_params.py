"""How the command line shows and parses its parameters (typer's own, adjusted):

* ``--help`` says what a value is in words — ``PATH``, ``INTEGER``, ``NUMBER``, ``TEXT`` or the
  choices, ``...`` for several — and ranges as 'from 1 to 2', never a Python type
  (``<list[Path]>``) or a usage line's ``{pipeline}``;
* an option that takes several values takes every word up to the next option, as a shell
  expands a glob (``--data A B C``), besides ``--data A --data B``.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any, get_args

from typer.core import TyperArgument, TyperOption


def spread(command: Any, args: list[str]) -> list[str]:
    """``args`` with the values after an option that takes several (``--data A B C``, as a shell
    expands ``--data *.log``) each given to it (``--data A --data B --data C``): the values run
    to the next option or ``--``."""
    many = {name for p in getattr(command, "params", []) if getattr(p, "multiple", False)
            for name in p.opts}
    if not many:
        return args
    out: list[str] = []
    taking = None
    for i, arg in enumerate(args):
        if arg == "--":
            return out + args[i:]
        if arg.startswith("-") and arg != "-":
            name = arg.split("=", 1)[0]
            taking = name if name in many else None
            out.append(arg)
            if taking and "=" not in arg and i + 1 < len(args):
                continue  # its first value follows as usual
        elif taking is not None and out and out[-1] != taking:
            out += [taking, arg]
        else:
            out.append(arg)
    return out


#: What a value is, in the words --help shows (``<list[Path]>`` → ``PATH...``).
_WORDS = {int: "INTEGER", float: "NUMBER", str: "TEXT", Path: "PATH"}


def _word(param: Any) -> str:
    """The value of ``param`` in words: its choices (``auto|nhat``), else PATH, INTEGER,
    NUMBER or TEXT."""
    desc = getattr(param, "type_descriptor", None)
    choices = getattr(desc, "choices", None)
    if choices:
        return "|".join(str(getattr(c, "value", c)) for c in choices)
    annotation = getattr(desc, "annotation", None)
    args = get_args(annotation)
    if getattr(desc, "is_list", False) and args:
        annotation = args[0]
    return _WORDS.get(annotation, "VALUE")


def _range(low: Any, high: Any) -> str | None:
    """A number's range in words: 'from 1 to 2', 'at least 0'."""
    if low is not None and high is not None:
        return f"from {low} to {high}"
    if low is not None:
        return f"at least {low}"
    return f"at most {high}" if high is not None else None


class _Argument(TyperArgument):
    """An argument shown by its name in capitals (``PIPELINE``, ``[DATA]...``), no type."""

    def display_type_rich(self, ctx: Any) -> str | None:
        return None

    def _rich_display_name(self) -> str:
        return self.display_name_raw + ("..." if self.nargs != 1 else "")

    def _usage_display_name(self) -> str:
        name = self.display_name_raw if self.required else f"[{self.display_name_raw}]"
        return name + ("..." if self.nargs != 1 else "")

    def _get_number_range_help_str(self) -> str | None:
        return _range(self.min, self.max)


class _Option(TyperOption):
    """An option whose value is shown in words (``--out PATH``, ``--workers INTEGER``); one that
    takes several values is shown with ``...`` (``--data PATH...``)."""

    def display_type_rich(self, ctx: Any) -> str | None:
        word = self.metavar or _word(self)
        return word + ("..." if self.multiple and not word.endswith("...") else "")

    def _get_number_range_help_str(self) -> str | None:
        return _range(self.min, self.max)

    def _get_default_string(self, *, ctx: Any, show_default_is_str: bool, default_value: Any) -> str:
        if show_default_is_str:  # a default said in words: as it is, not in parentheses
            return str(self.show_default)
        return super()._get_default_string(ctx=ctx, show_default_is_str=show_default_is_str,
                                           default_value=default_value)


def in_words(params: list[Any]) -> None:
    """Every parameter of a command shown in words in --help and the usage line."""
    for param in params:
        if isinstance(param, TyperArgument) and not isinstance(param, _Argument):
            param.__class__ = _Argument
            if param.metavar is None:
                param.metavar = (param.name or "value").upper()
        elif isinstance(param, TyperOption) and not isinstance(param, _Option):
            param.__class__ = _Option
