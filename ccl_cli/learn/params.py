"""What each constructor parameter of a learner accepts, declared once: in its annotation.

A learner (or a parameter group it derives from, :func:`parameters`) declares each constructor
parameter as an annotated class attribute::

    n_centres: Annotated[int, Interval(1, 100_000)] = 16
    selection: SelectionRule = "ratio"                  # a Literal: one of its values
    n_constraints: Annotated[int, Interval(0, 100_000)] | None = None
    tune: bool | Annotated[dict, Fields(budget=Annotated[float, Interval(0, None)])] = True

:func:`declared` reads the annotations; :meth:`ccl_cli.learn.base.Estimator._validate_params`
checks the parameters against them at the start of ``fit``, and the run spec
(:mod:`ccl_cli.spec`) builds each stage's pydantic schema from them. What an annotation
accepts (a union: any of its members):

* ``None``: the value None;
* ``Literal[...]``: one of the listed values (:class:`Options`);
* ``Annotated[int | float, Interval(low, high, closed="both")]``: a finite number of that type
  within the bounds (``None``: unbounded; an int is a float);
* ``Annotated[dict, Fields(key=annotation, ...)]``: a mapping whose keys are among those
  listed, each value valid against its own annotation (several ``Fields``: any of them);
* a type (``bool``, ``str``, ``dict[...]``, ``list[...]``, a class such as ``RBFBasis``):
  ``isinstance``, except that a bool is never an int or a float;
* ``Callable[...]``: any callable, e.g. a feature map; ``Any``: anything.

Every range is phrased one way, by :meth:`Interval.describe`: "<name> must be an integer
between 1 and 100000, got 0" (:func:`out_of_range`), in a learner's error and in the run
spec's alike. This module holds no NumPy (the command line reads declarations without it).
"""

from __future__ import annotations

import collections.abc
import difflib
import functools
import math
import numbers
import types
import typing
from collections.abc import Iterable, Mapping
from dataclasses import dataclass, replace
from typing import Annotated, Any, Literal

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


def _number(value: float, kind: type) -> str:
    return str(int(value)) if kind is int and float(value).is_integer() else f"{value:g}"


@dataclass(frozen=True)
class Interval:
    """A finite number in [low, high] (a bound None: open-ended); ``closed`` says which ends
    belong: "both", "left", "right" or "neither". ``type`` (int or float) is the annotated
    type: ``Annotated[int, Interval(1, 10)]`` is an integer from 1 to 10."""

    low: float | None
    high: float | None
    closed: str = "both"
    type: type = float

    def matches_type(self, value: Any) -> bool:
        kind = numbers.Integral if self.type is int else numbers.Real
        return isinstance(value, kind) and not isinstance(value, bool)

    def contains(self, value: Any) -> bool:
        """``value`` (a number of :attr:`type`) is finite and inside."""
        low_in, high_in = self.closed in ("both", "left"), self.closed in ("both", "right")
        return math.isfinite(value) and not (
            self.low is not None and (value < self.low or (value == self.low and not low_in))) and not (
            self.high is not None and (value > self.high or (value == self.high and not high_in)))

    def describe(self) -> str:
        """The one phrasing of a range: "an integer between 1 and 100000", "a number > 0",
        "a number ≥ 0 and < 1"."""
        noun = "an integer" if self.type is int else "a number"
        low_in, high_in = self.closed in ("both", "left"), self.closed in ("both", "right")
        low, high = (None if b is None else _number(b, self.type) for b in (self.low, self.high))
        if low is not None and high is not None and low_in and high_in:
            return f"{noun} between {low} and {high}"
        bounds = ([f"{'≥' if low_in else '>'} {low}"] if low is not None else []) + (
            [f"{'≤' if high_in else '<'} {high}"] if high is not None else [])
        return " ".join([noun, " and ".join(bounds)]).strip()

    def bounds(self) -> dict[str, float]:
        """The bounds as pydantic's ``Field`` takes them (``ge``/``gt``, ``le``/``lt``)."""
        out: dict[str, float] = {}
        if self.low is not None:
            out["ge" if self.closed in ("both", "left") else "gt"] = self.low
        if self.high is not None:
            out["le" if self.closed in ("both", "right") else "lt"] = self.high
        return out

    def field(self, unit: str | None = None) -> dict[str, Any]:
        """The keyword arguments of a pydantic ``Field`` holding this range: its bounds and its
        description (with ``unit``: "a number > 0 (s)")."""
        return {**self.bounds(), "description": self.describe() + (f" ({unit})" if unit else "")}


def out_of_range(name: str, value: Any, interval: Interval) -> str:
    """"<name> must be <the range>, got <value>" (:meth:`Interval.describe`)."""
    return f"{name} must be {interval.describe()}, got {value!r}"


@dataclass(frozen=True)
class Options:
    """One of ``values`` (all of ``type``): a ``Literal[...]`` annotation."""

    type: type
    values: frozenset

    @classmethod
    def of(cls, literal: Any) -> Options:
        """The options of a ``Literal[...]`` annotation."""
        values = typing.get_args(literal)
        return cls(type(values[0]), frozenset(values))

    def describe(self) -> str:
        return "one of " + ", ".join(sorted(map(str, self.values)))


class Fields:
    """A mapping whose keys are among those given, each value valid against its annotation:
    ``Annotated[dict, Fields(budget=Annotated[float, Interval(0, None)], grid=dict)]``."""

    def __init__(self, **fields: Any) -> None:
        self.fields: Mapping[str, Any] = types.MappingProxyType(fields)

    def __eq__(self, other: object) -> bool:
        return isinstance(other, Fields) and dict(self.fields) == dict(other.fields)

    def __hash__(self) -> int:
        return hash(tuple(self.fields))

    def __repr__(self) -> str:
        return f"Fields({', '.join(self.fields)})"

    def forms(self, key: str) -> list:
        """The forms the value under ``key`` may take (:func:`forms_of` its annotation)."""
        return forms_of(self.fields[key])

    def describe(self) -> str:
        return "a mapping with keys among " + ", ".join(self.fields)


_NOUNS = {int: "an integer", float: "a number", str: "a string", bool: "true or false", dict: "a mapping",
          list: "a list"}


def describe(form: Any) -> str:
    """What one form accepts, in words ("an integer between 1 and 10", "one of a, b")."""
    if form is None:
        return "None"
    if form is callable:
        return "a callable"
    if isinstance(form, type):
        return _NOUNS.get(form, f"a {form.__name__}")
    return form.describe()


def forms_of(hint: Any) -> list:
    """The forms an annotation accepts, in its order: None, a type, ``callable``, an
    :class:`Interval` (with the annotated type), :class:`Options`, :class:`Fields`."""
    if hint is None or hint is type(None):
        return [None]
    if hint is Any:
        return [object]
    origin = typing.get_origin(hint)
    if origin is Annotated:
        base, *meta = typing.get_args(hint)
        forms = [replace(m, type=base) if isinstance(m, Interval) else m for m in meta
                 if isinstance(m, Interval | Options | Fields)]
        return forms or forms_of(base)
    if origin is Literal:
        return [Options.of(hint)]
    if origin is typing.Union or origin is types.UnionType:
        return [f for arg in typing.get_args(hint) for f in forms_of(arg)]
    if hint is collections.abc.Callable or origin is collections.abc.Callable:
        return [callable]
    if origin is not None:  # dict[str, Any], list[int]: the container's type
        return [origin]
    if isinstance(hint, type):
        return [hint]
    raise TypeError(f"a parameter annotation ccl cannot check: {hint!r}")


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
            if form.contains(value):
                return None
            near = out_of_range(name, value, form)
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
        near = f"{name} must be {' or '.join(describe(f) for f in forms)}, got {value!r}"
    return near[:300]


def _fields_problem(value: Mapping, form: Fields, name: str) -> str | None:
    for key, sub in value.items():
        if key not in form.fields:
            close = difflib.get_close_matches(str(key), list(form.fields), n=1)
            hint = f"did you mean {close[0]!r}?" if close else f"keys: {', '.join(form.fields)}"
            return f"{name} has an unknown key {key!r} ({hint})"
        found = problem(sub, form.forms(key), f"{name}.{key}")
        if found is not None:
            return found
    return None


def validate_params(owner: str, constraints: Mapping[str, list], params: Mapping[str, Any]) -> None:
    """Raise ``ConfigError("<owner>: parameter n_centres must be an integer between 1 and
    100000, got 0")`` for the first parameter that matches none of its declared forms."""
    for name, value in params.items():
        found = problem(value, constraints[name], name)
        if found is not None:
            raise ConfigError(f"{owner}: parameter {found}")


#: A learner's seed (k-means, restarts, folds, subsets).
Seed = Annotated[int, Interval(0, MAX_SEED)]
#: The bounds of an iterative fit: passes at most, and the relative tolerance that stops it.
MaxIter = Annotated[int, Interval(1, 10_000_000)]
Tolerance = Annotated[float, Interval(0, None)]
#: Rows per block of a pass over the data (None: the learner's default).
ChunkSize = Annotated[int, Interval(1, None)] | None
#: A number ≥ 0 (a level, a penalty, a shrinkage).
NonNegative = Annotated[float, Interval(0, None)]
#: A fixed number of constraints (None: chosen by the learner's rule), and the most it may choose.
NConstraints = Annotated[int, Interval(0, 100_000)] | None
MaxConstraints = Annotated[int, Interval(1, 100_000)] | None
#: Folds of a cross-validation.
NFolds = Annotated[int, Interval(2, 1000)]
#: A length of time > 0, in seconds.
Seconds = Annotated[float, Interval(0, None, closed="neither")]


# -- parameter groups --------------------------------------------------------------------------
def parameters(cls: type) -> type:
    """Make the annotated class attributes of ``cls`` its keyword-only constructor
    parameters, stored unchanged (a dataclass without generated ``__eq__``/``__repr__``).

    A learner declares only its own parameters and inherits those of the groups it derives
    from (:class:`SeedParams`, ``BasisParams``, ``SelectionParams``, ...); each parameter's
    annotation says what it accepts (:func:`declared`)."""
    return dataclass(kw_only=True, eq=False, repr=False)(cls)


@parameters
class SeedParams:
    """``seed``: every random choice of the learner (k-means, restarts, folds, subsets)."""

    seed: Seed = 0


def parameter_hints(cls: type, extras: bool = False) -> dict[str, Any]:
    """The resolved annotation of each constructor parameter of ``cls`` (``extras``: with the
    ``Annotated`` declarations, else the plain types). A learner made by :func:`parameters`
    has them on its class and its parameter groups, each resolved in the module that declares
    it; a hand-written constructor (``Tuned``, ``PerDemonstration``) has them on itself."""
    import dataclasses
    import inspect

    source = cls if dataclasses.is_dataclass(cls) else cls.__init__
    hints = typing.get_type_hints(source, include_extras=extras)
    return {name: hints.get(name) for name in inspect.signature(cls.__init__).parameters if name != "self"}


@functools.cache
def declared(cls: type) -> dict[str, list]:
    """Constructor parameter of ``cls`` → the forms its annotation accepts (:func:`forms_of`):
    the one declaration its validation and the run spec read."""
    hints = parameter_hints(cls, extras=True)
    missing = [name for name, hint in hints.items() if hint is None]
    if missing:
        raise TypeError(f"{cls.__name__}: parameters without an annotation: {', '.join(missing)}")
    return {name: forms_of(hint) for name, hint in hints.items()}
