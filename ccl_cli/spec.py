"""The typed run spec: every option of a ccl run, validated once at the boundary.

:class:`RunSpec` is the whole configuration of a run — ``seed``, ``data`` (what to read:
:class:`ccl_cli.io.options.DataOptions`, plus the held-out ``test`` split), one section per
stage (``learn-v``, ``learn-a``, ``learn-pi``, ``evaluate``), ``metrics``, ``output`` and the
``stages`` to run. It is the one place the schema lives, assembled from the parts that own
their options:

* a stage section holds the constructor parameters of its estimators, read from each
  estimator's signature and the annotation that declares each parameter
  (:func:`ccl_cli.learn.params.declared`): names, choices, ranges. A parameter the user did
  not set stays ``None`` and the estimator's own default applies, so the library and the
  command line share one set of defaults;
* the app-level options of a stage (``learn-a.method``: which estimator; ``on``: which
  observations; ``per_demo``; ``learn-pi.projections``, ``baseline``) are declared here;
* the reading options are the readers' own (:mod:`ccl_cli.io.options`).

:mod:`ccl_cli.config` reads YAML, merges command-line flags and turns validation errors into
``file:line: message``; nothing below the app layer reads a config mapping.
"""

from __future__ import annotations

import inspect
import typing
from collections.abc import Iterable
from functools import cache
from typing import Annotated, Any, Literal

from pydantic import BaseModel, ConfigDict, Field, create_model

# the fixed choices (learn-a's ``method`` is one of CONSTRAINT_METHODS), declared without NumPy or
# pydantic for the command line's --help
from ccl_cli.choices import (
    CONVENTION,
    DEFAULT_CONSTRAINT_METHOD,
    TEST_FRACTION,
    ConstraintMethod,
    Convention,
    On,
    Projections,
)
from ccl_cli.io.options import DataOptions
from ccl_cli.learn import defaults
from ccl_cli.learn.params import MAX_SEED, Fields, Interval, Options, declared, describe

STAGES = ("learn-v", "learn-a", "learn-pi", "evaluate")


class Section(BaseModel):
    """Common ground of the spec's models: frozen, strict (no string becomes a number), no
    unknown keys, finite numbers; YAML's dashed keys (``learn-a``) are the aliases."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False,
                              populate_by_name=True, defer_build=True)

    def given(self) -> dict[str, Any]:
        """The options set in the config (or by flags), by name, as validated."""
        return {name: getattr(self, name) for name in self.model_fields_set}


# -- estimator parameters → pydantic fields ---------------------------------------------------
#: The forms a YAML config can hold (not a callable, nor a Python object such as a fitted basis).
_CONFIG_TYPES = (bool, str, int, float, dict, list)


def _in_config(form: Any) -> bool:
    return isinstance(form, Interval | Options | Fields) or form in _CONFIG_TYPES


def _type_of(form: Any, name: str) -> Any:
    """The pydantic annotation of one declared form; None for forms a YAML config cannot
    hold (callables, Python objects such as a fitted basis)."""
    if form is None:
        return type(None)
    if isinstance(form, Interval):
        return Annotated[form.type, Field(**form.bounds())]
    if isinstance(form, Options):
        return Literal[tuple(sorted(form.values))]
    if isinstance(form, Fields):  # named by its first key too: two mappings of one parameter differ
        return _fields_model(f"{name}_{next(iter(form.fields))}", form)
    if form in (bool, str):
        return form
    if form is dict:
        return dict[str, Any]
    if form is list:
        return list[Any]
    return None


@cache
def _fields_model(name: str, form: Fields) -> type[Section]:
    """A section model for a mapping-valued parameter (e.g. ``basis: {kind, n_centres, ...}``)."""
    return create_model(f"{name.title().replace('_', '')}Options", __base__=Section,
                        **{key: _field(form.forms(key), key) for key in form.fields})


def _field(forms: Iterable[Any], name: str) -> tuple[Any, Any]:
    """(annotation, Field) of a parameter declared by ``forms``; default None (unset)."""
    forms = list(forms)
    types = [t for t in (_type_of(f, name) for f in forms) if t is not None]
    types = [t for t in dict.fromkeys(types) if t is not type(None)]
    words = [describe(f) for f in forms if _in_config(f)]
    annotation = typing.Union[tuple(types)] if len(types) > 1 else types[0]  # noqa: UP007 - a runtime tuple
    return annotation | None, Field(None, description=" or ".join(dict.fromkeys(words)) or None)


def _parameters(classes: Iterable[type], rename: dict[tuple[type, str], str] | None = None,
                skip: tuple[str, ...] = ("seed",)) -> dict[str, tuple[Any, Any]]:
    """The constructor parameters of ``classes`` as section fields (a parameter several
    classes share is declared once); ``rename`` maps (class, parameter) to its config key."""
    out: dict[str, tuple[Any, Any]] = {}
    for cls in classes:
        for name in inspect.signature(cls.__init__).parameters:
            if name in ("self", *skip):
                continue
            key = (rename or {}).get((cls, name), name)
            out.setdefault(key, _field(declared(cls)[name], key))
    return out


# -- stage sections -----------------------------------------------------------------------------
def _stage_classes() -> dict[str, tuple[type, ...]]:
    from ccl_cli.learn.constraint import (
        AutoConstraint,
        KnownFeatureConstraint,
        LinearConstraint,
        ManifoldConstraint,
        PerSegment,
        PerWindow,
        StateDependentConstraint,
        StateIndependentConstraint,
    )
    from ccl_cli.learn.nullspace import NullSpaceComponent
    from ccl_cli.learn.policy import PolicyLearner

    return {"learn-v": (NullSpaceComponent,), "learn-pi": (PolicyLearner,),
            "learn-a": (StateIndependentConstraint, StateDependentConstraint, KnownFeatureConstraint,
                        LinearConstraint, AutoConstraint, PerWindow, PerSegment, ManifoldConstraint)}


#: learn-a ``method`` → the estimator class's name (the class itself: :func:`constraint_class`)
CONSTRAINT_METHODS = {"auto": "AutoConstraint", "nhat": "StateIndependentConstraint",
                      "alpha": "StateDependentConstraint", "lambda": "KnownFeatureConstraint",
                      "linear": "LinearConstraint", "per_window": "PerWindow", "per_segment": "PerSegment",
                      "manifold": "ManifoldConstraint"}
#: config keys that are not the estimator's own names: (method, config key) → parameter
RENAMED = {("nhat", "variant"): "method"}


def constraint_class(method: str) -> type:
    """The estimator of a learn-a ``method``."""
    return next(c for c in _stage_classes()["learn-a"] if c.__name__ == CONSTRAINT_METHODS[method])


class StageSection(Section):
    """A stage's options: its estimators' parameters (None: the estimator's default) and
    the app-level options of the stage."""

    def estimator_params(self, cls: type) -> dict[str, Any]:
        """The parameters of ``cls`` that are set, by the estimator's own names."""
        names = set(inspect.signature(cls.__init__).parameters)
        out = {}
        for key, value in self.given().items():
            name = RENAMED.get((getattr(self, "method", None), key), key)
            if name in names and value is not None and key not in self.APP_KEYS:
                out[name] = _plain(value)
        return out

    APP_KEYS: typing.ClassVar[tuple[str, ...]] = ()


def _plain(value: Any) -> Any:
    """Section models inside a parameter (a basis or tune mapping) back to plain dicts."""
    if isinstance(value, BaseModel):
        return {k: _plain(v) for k, v in value.model_dump(exclude_none=True).items()}
    return value


@cache
def stage_models() -> dict[str, type[StageSection]]:
    """The section model of each stage (built once, from the estimators)."""
    classes = _stage_classes()
    on = (On, Field("auto"))
    nhat = next(c for c in classes["learn-a"] if c.__name__ == "StateIndependentConstraint")
    learn_a = _parameters(classes["learn-a"], rename={(nhat, "method"): "variant"})
    learn_a.update(method=(ConstraintMethod, Field(DEFAULT_CONSTRAINT_METHOD)), on=on,
                   per_demo=(bool, Field(False)))
    learn_pi = _parameters(classes["learn-pi"])
    cutoff_type, cutoff = learn_pi["cutoff"]
    learn_pi.update(
        cutoff=(cutoff_type | Literal["absolute", "relative"],
                Field(None, description=f"{cutoff.description}, or absolute or relative (the cut-off rule)")),
        on=on, projections=(Projections, Field("auto")), baseline=(bool, Field(True)))
    models = {
        "learn-v": create_model("LearnV", __base__=StageSection, **_parameters(classes["learn-v"])),
        "learn-a": create_model("LearnA", __base__=StageSection, **learn_a),
        "learn-pi": create_model("LearnPi", __base__=StageSection, **learn_pi),
        "evaluate": create_model("Evaluate", __base__=StageSection,
                                 convention=(Convention | None, Field(None))),
    }
    models["learn-a"].APP_KEYS = ("method", "on", "per_demo")
    models["learn-pi"].APP_KEYS = ("on", "projections", "baseline")
    return models


# -- the run ------------------------------------------------------------------------------------
#: A seed: the range of a learner's (:data:`ccl_cli.learn.params.Seed`).
_SEED = Interval(0, MAX_SEED, type=int)


class TestSplit(Section):
    """The held-out test set: ``fraction`` of the demonstrations (or time blocks), seeded; the
    file's stored masks when ``use_masks``; by demonstration from ``min_demos`` of them, else
    ``blocks`` contiguous time blocks with ``gap`` samples dropped at each boundary (default:
    the derivative window)."""

    fraction: float = Field(TEST_FRACTION, **Interval(0, 1).field())
    seed: int = Field(0, **_SEED.field())
    use_masks: bool = True
    gap: int | None = Field(None, **Interval(0, 1_000_000, type=int).field())
    min_demos: int = Field(defaults.MIN_DEMOS, **Interval(2, 1_000_000, type=int).field())
    blocks: int = Field(defaults.N_BLOCKS, **Interval(2, 1_000_000, type=int).field())


class Data(DataOptions):
    """The ``data`` section: the readers' options (:class:`~ccl_cli.io.options.DataOptions`)
    and the held-out ``test`` split."""

    test: TestSplit = TestSplit()

    def reading(self) -> DataOptions:
        """The readers' part of the section."""
        return DataOptions.model_validate(self.model_dump(exclude={"test"}, exclude_unset=True))


class Metrics(Section):
    convention: Convention = CONVENTION


class Output(Section):
    """``plots``: draw the figures; ``format``: png, or svg / pdf (vector, for a paper); ``html``:
    also write report.html (the report with its figures embedded and a 3-D view of the states)."""

    plots: bool = True
    format: Literal["png", "svg", "pdf"] = "png"
    html: bool = False


class StageItem(Section):
    """One entry of ``stages``: a stage name and the options overriding its section."""

    name: Literal[STAGES]
    options: dict[str, Any] = {}


def run_spec_model() -> type[BaseModel]:
    """The :class:`RunSpec` model (its stage sections are built from the estimators)."""
    return _run_spec_model()


@cache
def _run_spec_model() -> type[BaseModel]:
    m = stage_models()
    stages: dict[str, Any] = {
        key.replace("-", "_"): (m[key], Field(default_factory=m[key], alias=key)) for key in STAGES}
    return create_model(
        "RunSpec", __base__=RunSpecBase,
        seed=(int, Field(0, **_SEED.field())),
        data=(Data, Field(default_factory=Data)), **stages,
        metrics=(Metrics, Field(default_factory=Metrics)), output=(Output, Field(default_factory=Output)),
        stages=(list[str | dict[str, Any]] | None, Field(None, description="a list of stage names or "
                                                          "one-key mappings")))


class RunSpecBase(Section):
    """Methods of the run spec (its fields: :func:`run_spec_model`)."""

    def section(self, name: str) -> StageSection:
        return getattr(self, name.replace("-", "_"))

    def stage(self, name: str, options: dict[str, Any] | None = None) -> StageSection:
        """Stage ``name``'s options: its section with a ``stages`` item's ``options`` on top."""
        section = self.section(name)
        if not options:
            return section
        merged = {**section.model_dump(exclude_unset=True, by_alias=True), **options}
        return type(section).model_validate(merged)
