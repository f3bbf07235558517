"""What each constructor parameter of a learner accepts, declared once as plain data.

Every learner declares beside its constructor::

    _parameter_constraints = {
        "n_centres": [Interval(int, 1, 100_000)],
        "selection": [Options(str, {"ratio", "threshold", "eigengap", "cv"})],
        "n_constraints": [Interval(int, 0, 100_000), None],
        "tune": [bool, Fields({"budget": [Interval(float, 0, None)], ...})],
    }

The format (read by :meth:`ccl_cli.learn.base.Estimator._validate_params` at the start of
``fit`` and by the run spec, which builds each stage's schema from it):

* one key per constructor parameter, mapped to the list of forms it accepts; a value is
  valid when it matches any form:

  - ``None``: the value may be None;
  - a type (``bool``, ``str``, ``dict``, a class such as ``RBFBasis``): ``isinstance``,
    except that a bool is never an int or a float;
  - ``callable`` (the builtin): any callable, e.g. a feature map;
  - :class:`Interval` ``(int | float, low, high, closed="both")``: a finite number of
    that type within the bounds (``None``: unbounded; an int is a float);
  - :class:`Options` ``(str, {...})``: one of the listed values;
  - :class:`Fields` ``({key: [forms]})``: a mapping whose keys are among those listed,
    each value valid against its own forms.

This module holds no NumPy (the command line reads declarations without it).
"""

from __future__ import annotations

import difflib
import math
import numbers
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass
from typing import Any, ClassVar, Literal

from ccl_cli.errors import ConfigError

# -- the fixed choices of learner parameters: named here, without NumPy, so the command line
# -- lists them in --help; the learners annotate their parameters with them
SelectionRule = Literal["ratio", "threshold", "eigengap", "cv", "noise"]
PolicyMethod = Literal["pi", "pi-weighted", "pi-coupled", "lwpi", "dpl"]
CutoffRule = Literal["relative", "absolute"]
BasisKind = Literal["rbf", "linear"]
ArmName = Literal["arm2", "arm7"]
Regressors = Literal["identity", "rbf", "polynomial"]
TaskRegressors = Literal["constant", "polynomial", "rbf"]
Whiten = Literal["rms", "errors", "none"]
NhatMethod = Literal["closed_form", "search"]

#: Largest seed: NumPy's generators take any non-negative integer below 2^63 here.
MAX_SEED = 2**63 - 1


@dataclass(frozen=True)
class Interval:
    """A finite number of ``type`` (int or float) in [low, high] (bounds None: open-ended);
    ``closed`` says which ends belong: "both", "left", "right" or "neither"."""

    type: type
    low: float | None
    high: float | None
    closed: str = "both"

    def matches_type(self, value: Any) -> bool:
        kind = numbers.Integral if self.type is int else numbers.Real
        return isinstance(value, kind) and not isinstance(value, bool)

    def violation(self, value: Any) -> str | None:
        """None when ``value`` is inside, else what is wrong ("must be ≥ 1")."""
        if not math.isfinite(value):
            return "must be a finite number"
        low_in = self.closed in ("both", "left")
        high_in = self.closed in ("both", "right")
        if self.low is not None and (value < self.low or (value == self.low and not low_in)):
            return f"must be {'≥' if low_in else '>'} {self.low:g}"
        if self.high is not None and (value > self.high or (value == self.high and not high_in)):
            return f"must be {'≤' if high_in else '<'} {self.high:g}"
        return None

    def describe(self) -> str:
        noun = "an integer" if self.type is int else "a number"
        low_sign = "≥" if self.closed in ("both", "left") else ">"
        high_sign = "≤" if self.closed in ("both", "right") else "<"
        bounds = ([f"{low_sign} {self.low:g}"] if self.low is not None else []) + (
            [f"{high_sign} {self.high:g}"] if self.high is not None else [])
        return " ".join([noun, " and ".join(bounds)]).strip()


@dataclass(frozen=True)
class Options:
    """One of ``values`` (all of ``type``)."""

    type: type
    values: frozenset

    @classmethod
    def of(cls, literal: Any) -> Options:
        """The options of a ``Literal[...]`` annotation (one list of choices for both)."""
        values = typing.get_args(literal)
        return cls(type(values[0]), frozenset(values))

    def describe(self) -> str:
        return "one of " + ", ".join(sorted(map(str, self.values)))


@dataclass(frozen=True)
class Fields:
    """A mapping whose keys are among ``fields`` (key → forms), each value valid."""

    fields: Mapping[str, list]

    def describe(self) -> str:
        return "a mapping with keys among " + ", ".join(self.fields)


_NOUNS = {int: "an integer", float: "a number", str: "a string", bool: "true or false", dict: "a mapping",
          list: "a list"}


def _describe(form: Any) -> str:
    if form is None:
        return "None"
    if form is callable:
        return "a callable"
    if isinstance(form, type):
        return _NOUNS.get(form, f"a {form.__name__}")
    return form.describe()


def _is_instance(value: Any, kind: type) -> bool:
    if isinstance(value, bool) and kind is not bool:
        return kind is object
    if kind is float:
        return isinstance(value, numbers.Real)
    if kind is int:
        return isinstance(value, numbers.Integral)
    return isinstance(value, kind)


def problem(value: Any, forms: Iterable[Any], name: str) -> str | None:
    """None when ``value`` matches one of ``forms``; else "<name> must be …, got …"."""
    forms = list(forms)
    near: str | None = None  # what a form whose type matched says about the value
    for form in forms:
        if form is None or form is callable or isinstance(form, type):
            if (value is None if form is None else callable(value) and not isinstance(value, type)
                    if form is callable else _is_instance(value, form)):
                return None
        elif isinstance(form, Interval) and form.matches_type(value):
            near = form.violation(value)
            if near is None:
                return None
            near = f"{name} {near}, got {value!r}"
        elif isinstance(form, Options) and isinstance(value, form.type) and not isinstance(value, bool):
            if value in form.values:
                return None
            close = difflib.get_close_matches(str(value), sorted(map(str, form.values)), n=1)
            near = f"{name} must be {form.describe()}, got {value!r}" + (
                f" (did you mean {close[0]!r}?)" if close else "")
        elif isinstance(form, Fields) and isinstance(value, Mapping):
            near = _fields_problem(value, form, name)
            if near is None:
                return None
    if near is None:
        near = f"{name} must be {' or '.join(_describe(f) for f in forms)}, got {value!r}"
    return near[:300]


def _fields_problem(value: Mapping, form: Fields, name: str) -> str | None:
    for key, sub in value.items():
        if key not in form.fields:
            close = difflib.get_close_matches(str(key), list(form.fields), n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"keys: {', '.join(form.fields)}"
            return f"{name} has an unknown key {key!r} ({hint})"
        found = problem(sub, form.fields[key], f"{name}.{key}")
        if found is not None:
            return found
    return None


def validate_params(owner: str, constraints: Mapping[str, list], params: Mapping[str, Any]) -> None:
    """Raise ``ConfigError("<owner>: parameter n_centres must be ≥ 1, got 0")`` for the
    first parameter that matches none of its declared forms."""
    for name, value in params.items():
        found = problem(value, constraints[name], name)
        if found is not None:
            raise ConfigError(f"{owner}: parameter {found}")


#: The seed of a learner (k-means, restarts, folds, subsets).
SEED = {"seed": [Interval(int, 0, MAX_SEED)]}
#: The bounds of an iterative fit: passes at most and the relative tolerance that stops it.
ITERATION_PARAMS = {"max_iter": [Interval(int, 1, 10_000_000)], "tol": [Interval(float, 0, None)]}


# -- parameter groups --------------------------------------------------------------------------
def parameters(cls: type) -> type:
    """Make the annotated class attributes of ``cls`` its keyword-only constructor
    parameters, stored unchanged (a dataclass without generated ``__eq__``/``__repr__``).

    A learner declares only its own parameters and inherits those of the groups it derives
    from (:class:`SeedParams`, ``BasisParams``, ``SelectionParams``, ...); a group declares
    its ``_parameter_constraints`` beside its fields, and
    :class:`~ccl_cli.learn.base.Estimator` merges the declarations of every base."""
    return dataclass(kw_only=True, eq=False, repr=False)(cls)


@parameters
class SeedParams:
    """``seed``: every random choice of the learner (k-means, restarts, folds, subsets)."""

    _parameter_constraints: ClassVar[dict[str, list]] = SEED
    seed: int = 0


def parameter_hints(cls: type) -> dict[str, Any]:
    """The resolved annotation of each constructor parameter of ``cls``: a parameter group's
    annotation is resolved in the module that declares the group (the dataclass-made
    ``__init__`` of a learner carries its annotations unresolved)."""
    import inspect

    try:
        hints = typing.get_type_hints(cls.__init__)
    except NameError:
        hints = typing.get_type_hints(cls)
    return {name: hints.get(name) for name in inspect.signature(cls.__init__).parameters if name != "self"}
