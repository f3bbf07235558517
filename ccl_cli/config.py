"""Loading a run's configuration: YAML → command-line flags merged in → the typed run spec.

The schema itself lives in :mod:`ccl_cli.spec`; this module reads the YAML safely
(:func:`ccl_cli.io.yamlsafe.read_yaml`), remembers the line of every key, applies the flags
(a flag overrides the file at any depth, also inside a ``stages`` item), resolves the stages
to run, and turns every validation error into one line naming where it is:
``cfg.yaml:4: unknown key 'n_centers' in learn-a (did you mean 'n_centres'?)``, or the flag
(``--n-centres: ...``).
"""

from __future__ import annotations

import copy
import difflib
import logging
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any

from ccl_cli.errors import ConfigError

FLAGS = "command line"


def _lines(node: Any, path: tuple = (), out: dict | None = None) -> dict[tuple, int]:
    """Line (1-based) of every key and list item of a composed YAML document."""
    import yaml

    out = {} if out is None else out
    out.setdefault(path, node.start_mark.line + 1)
    if isinstance(node, yaml.MappingNode):
        for key, value in node.value:
            k = key.value
            out[(*path, k)] = key.start_mark.line + 1
            _lines(value, (*path, k), out)
    elif isinstance(node, yaml.SequenceNode):
        for i, item in enumerate(node.value):
            _lines(item, (*path, i), out)
    return out


@dataclass(frozen=True)
class Config:
    """A loaded configuration: the validated :class:`~ccl_cli.spec.RunSpec` (``spec``), the
    mapping it was validated from (the YAML with the flags merged in: ``raw``, recorded in
    run.json, config.yaml and model files), the stages to run with their resolved options,
    and where it came from (``source``, ``base`` for relative paths, ``lines``)."""

    spec: Any
    raw: dict[str, Any]
    stage_items: tuple[tuple[str, Any], ...] = ()
    source: str = "<flags>"
    base: Path | None = None
    lines: dict[tuple, int] = field(default_factory=dict, repr=False)

    def stages(self, default: list[str] | None = None) -> list[tuple[str, Any]]:
        """The stages to run as (name, options) pairs: the ``stages`` list, or ``default``
        names with their sections' options."""
        if self.stage_items:
            return list(self.stage_items)
        if default is None:
            raise ConfigError(f"{self.source}: no stages to run (add a stages: list)")
        return [(name, self.spec.section(name)) for name in default]


# -- loading -----------------------------------------------------------------------------------
def load(path: str | Path | None, flags: dict[str, Any] | None = None) -> Config:
    """The config of YAML file ``path`` (None: none) with command-line ``flags`` on top
    (values None are ignored). Raises :class:`ConfigError` with the file and line, or the flag."""
    from ccl_cli.io.yamlsafe import read_yaml

    raw: dict[str, Any] = {}
    lines: dict[tuple, int] = {}
    source, base = "<flags>", None
    if path is not None:
        path = Path(path)
        data, node = read_yaml(path, "config")
        if data is None:
            data = {}
        if not isinstance(data, dict):
            raise ConfigError(f"{path}:1: the config must be a mapping of sections (data, learn-a, ...)")
        raw, lines, source, base = data, (_lines(node) if node is not None else {}), str(path), path.parent
    return from_mapping(raw, source=source, base=base, lines=lines, flags=flags)


def from_mapping(raw: dict[str, Any], *, source: str = "<flags>", base: Path | None = None,
                 lines: dict[tuple, int] | None = None, flags: dict[str, Any] | None = None) -> Config:
    """The config of a mapping (a manifest job's, or a test's), validated like a file's."""
    from ccl_cli import spec

    lines = lines or {}
    flags = _drop_none(flags or {})
    if flags:
        _validate(spec.run_spec_model(), _apply_flags({}, flags), FLAGS, {}, ())
    merged = _apply_flags(raw, flags)
    run = _validate(spec.run_spec_model(), merged, source, lines, ())
    items = tuple(_stage_item(run, item, i, flags, source, lines)
                  for i, item in enumerate(merged.get("stages") or []))
    for name, options in [*(("learn-a", run.section("learn-a")),), *items]:
        if name == "learn-a":
            _check_method_keys(options, source, lines)
    return Config(run, merged, items, source, base, lines)


def _stage_item(run: Any, item: Any, i: int, flags: dict[str, Any], source: str,
                lines: dict[tuple, int]) -> tuple[str, Any]:
    """A ``stages`` item → (name, its section's options with the item's and the flags' on top)."""
    from ccl_cli import spec

    where = _where(source, lines, ("stages", i))
    if isinstance(item, str):
        name, options = item, {}
    elif isinstance(item, dict) and len(item) == 1:
        name, options = next(iter(item.items()))
        options = options or {}
    else:
        raise ConfigError(f"{where}: each stage is a name or a one-key mapping (e.g. - learn-a: "
                          f"{{method: nhat}}), got {item!r}"[:300])
    if name not in spec.STAGES:
        close = difflib.get_close_matches(str(name), spec.STAGES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (stages: {', '.join(spec.STAGES)})"
        raise ConfigError(f"{where}: unknown stage {name!r}{hint}")
    if not isinstance(options, dict):
        raise ConfigError(f"{where}: the options of stage {name} must be a mapping, got {options!r}"[:300])
    section = run.section(name).model_dump(exclude_unset=True, by_alias=True)
    merged = _override(deep_merge(section, options), flags.get(name) or {})
    model = spec.stage_models()[name]
    return name, _validate(model, merged, source, lines, ("stages", i, name), label=name)


def _check_method_keys(options: Any, source: str, lines: dict[tuple, int]) -> None:
    """A learn-a option that the chosen method does not take is ignored with a warning (a
    manifest may switch the method of a config written for another)."""
    import inspect

    from ccl_cli import spec

    params = set(inspect.signature(spec.constraint_class(options.method).__init__).parameters)
    for key in sorted(options.model_fields_set - set(type(options).APP_KEYS)):
        name = spec.RENAMED.get((options.method, key), key)
        if name not in params:
            takes = [m for m in spec.CONSTRAINT_METHODS if spec.RENAMED.get((m, key), key) in
                     inspect.signature(spec.constraint_class(m).__init__).parameters]
            logging.getLogger("ccl").warning("%s: learn-a.%s applies to method %s, not %s: ignored",
                                             _where(source, lines, ("learn-a", key)), key, " or ".join(takes),
                                             options.method)


# -- flags -------------------------------------------------------------------------------------
def deep_merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


def _drop_none(d: dict) -> dict:
    out = {}
    for k, v in d.items():
        if isinstance(v, dict):
            v = _drop_none(v)
            if v:
                out[k] = v
        elif v is not None:
            out[k] = v
    return out


def _override(opts: dict, flags: dict) -> dict:
    """``opts`` with a stage's flag values on top, at any depth: ``--n-centres`` also sets
    ``basis.n_centres`` and ``--basis KIND`` sets ``basis.kind`` when the basis is a mapping
    (so a flag is never shadowed by, nor wipes out, a basis mapping of the config); either
    flag switches the stage's basis search off (``tune: false``), so the given basis is used."""
    if not flags:
        return opts
    out = deep_merge(opts, {k: v for k, v in flags.items() if k != "basis"})
    if "basis" in flags:
        old = opts.get("basis")
        out["basis"] = {**old, "kind": flags["basis"]} if isinstance(old, dict) and \
            isinstance(flags["basis"], str) else copy.deepcopy(flags["basis"])
    if "n_centres" in flags and isinstance(out.get("basis"), dict):
        out["basis"] = {**out["basis"], "n_centres": flags["n_centres"]}
    if ("n_centres" in flags or "basis" in flags) and "tune" not in flags:
        out["tune"] = False  # a basis given on the command line is used, not searched over
    return out


def _apply_flags(raw: dict[str, Any], flags: dict[str, Any]) -> dict[str, Any]:
    """``raw`` with the flags merged in (stage sections with :func:`_override`)."""
    from ccl_cli.spec import STAGES

    out = copy.deepcopy(raw)
    for key, value in flags.items():
        if key in STAGES and isinstance(value, dict):
            section = out.get(key)
            out[key] = _override(section if isinstance(section, dict) else {}, value)
        elif isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


# -- validation errors as one line -------------------------------------------------------------
#: config keys whose flag is not named after the key alone
FLAG_NAMES = {("data", "test", "fraction"): "--test-fraction", ("metrics", "convention"): "--convention"}


def _where(source: str, lines: dict[tuple, int], path: tuple) -> str:
    if source == FLAGS and path:
        if tuple(path[:3]) in FLAG_NAMES or tuple(path[:2]) in FLAG_NAMES:
            return FLAG_NAMES.get(tuple(path[:3])) or FLAG_NAMES[tuple(path[:2])]
        last = next((p for p in reversed(path) if isinstance(p, str)), "")
        return "--" + last.replace("_", "-")
    for cut in range(len(path), -1, -1):
        line = lines.get(path[:cut])
        if line is not None:
            return f"{source}:{line}"
    return source


def _dotted(path: tuple) -> str:
    return ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in path).replace(".[", "[")


def _validate(model: type, raw: Any, source: str, lines: dict[tuple, int], base: tuple,
              label: str = "") -> Any:
    """``model.model_validate(raw)``, or one ConfigError naming the place (file:line or flag)."""
    from pydantic import ValidationError

    try:
        return model.model_validate(raw)
    except ValidationError as exc:
        path, message = describe(exc, model, label, raw)
        raise ConfigError(f"{_where(source, lines, (*base, *path))}: {message}"[:300]) from None


_PHRASES = {"int_type": "an integer", "float_type": "a number", "string_type": "a string",
            "bool_type": "true or false", "list_type": "a list", "model_type": "a mapping",
            "dict_type": "a mapping", "finite_number": "a finite number", "is_instance_of": "a path",
            "model_attributes_type": "a mapping", "dataclass_type": "a mapping"}


def _fields_of(annotation: Any) -> list[type]:
    """The pydantic models inside an annotation (a model, or the models of a union)."""
    import typing

    from pydantic import BaseModel

    if isinstance(annotation, type) and issubclass(annotation, BaseModel):
        return [annotation]
    return [m for a in typing.get_args(annotation) for m in _fields_of(a)]


def describe(exc: Any, model: type, label: str = "", raw: Any = None) -> tuple[tuple, str]:
    """The most specific error of a pydantic ValidationError as (key path, message): the
    error that reached deepest into the config (a union tries every member; when several
    members fail at the same key, the key's description says what it takes)."""
    errors = exc.errors(include_url=False)
    located = [(_keys(e["loc"], model, e["type"] == "extra_forbidden"), e) for e in errors]
    depth = max(len(keys[0]) for keys, _ in located)
    deepest = [(keys, e) for keys, e in located if len(keys[0]) == depth]
    # a mapping that fits no member of a union: blame the member sharing the most of its keys
    deepest.sort(key=lambda item: -_overlap(item[0][1], item[0][0], item[1]["type"] == "extra_forbidden",
                                            raw))
    (path, cls, description), err = deepest[0]
    shown = (label,) + path if label else path
    name = _dotted(shown)
    kind = err["type"]
    got = f", got {err['input']!r}"
    if len({e["type"] for _, e in deepest}) > 1 and description:
        return path, f"{name} must be {description}{got}"
    if kind == "extra_forbidden":
        valid = [f.alias or k for k, f in cls.model_fields.items()] if cls is not None else []
        key = path[-1]
        close = difflib.get_close_matches(str(key), valid, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (valid: {', '.join(valid)})"
        where = f"in {_dotted(shown[:-1])}" if shown[:-1] else "at the top level"
        return path, f"unknown key {key!r} {where}{hint}"
    if kind == "literal_error":
        options = [o.strip().strip("'") for o in err["ctx"]["expected"].replace(" or ", ", ").split(",")]
        close = difflib.get_close_matches(str(err["input"]), options, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else ""
        return path, f"{name} must be one of {', '.join(options)}{got}{hint}"
    if kind == "value_error":
        text = str(err["ctx"]["error"])
        return path, f"{name}{'' if text.startswith('[') else ' '}{text}{'' if 'got ' in text else got}"
    if kind == "finite_number":
        return path, f"{name} must be a finite number{got}"
    what = description or _PHRASES.get(kind) or err["msg"][0].lower() + err["msg"][1:]
    return path, f"{name} must be {what}{got}"


def _overlap(cls: Any, keys: tuple, unknown: bool, raw: Any) -> int:
    """How many keys of the mapping an error is about (at ``keys`` in ``raw``; the parent of an
    unknown key) are fields of model ``cls``."""
    value = raw
    for key in keys[:-1] if unknown else keys:
        if not isinstance(value, dict | list):
            return 0
        try:
            value = value[key]
        except (KeyError, IndexError, TypeError):
            return 0
    if not isinstance(value, dict) or cls is None:
        return 0
    return len({f.alias or k for k, f in cls.model_fields.items()} & set(map(str, value)))


def _keys(loc: tuple, model: type, unknown: bool) -> tuple[tuple, type | None, str | None]:
    """The config keys of an error location (union members' tags left out), the model the
    last key belongs to, and that key's description; ``unknown``: the last element of the
    location is a key the model does not have."""
    path: list[Any] = []
    cls: Any = model
    members: list[type] = []
    description = None
    for i, part in enumerate(loc):
        if isinstance(part, int):
            path.append(part)
            continue
        fields = {} if cls is None else {(f.alias or k): f for k, f in cls.model_fields.items()}
        if part in fields:
            info = fields[part]
            path.append(part)
            description = info.description
            members = _fields_of(info.annotation)
            cls = members[0] if len(members) == 1 else None
            continue
        tagged = next((m for m in members if m.__name__ == part), None)
        if tagged is not None:  # the union member this error is about
            cls = tagged
            continue
        if unknown and i == len(loc) - 1:
            path.append(part)
        break  # the tag of a member that is not a section (e.g. "literal['a','b']", "int")
    return tuple(path), cls, description
