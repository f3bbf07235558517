"""The YAML configuration: schema, defaults and validation with precise messages.

A config has a ``data`` section (what to read, see README "Config"), optional stage
sections (``learn-v``, ``learn-a``, ``learn-pi``, ``evaluate``) holding each stage's
options, an optional ``stages`` list for ``ccl run`` (names, or one-key mappings of a
name to options that override the stage section), ``metrics``, ``output`` and ``seed``.

Unknown keys and wrong types are rejected with the file, the line and the closest
valid key. Command-line flags override the file (see :func:`merge`).
"""

from __future__ import annotations

import copy
import difflib
from pathlib import Path
from typing import Any

import yaml

from ccl_cli.errors import ConfigError
from ccl_cli.io.yamlsafe import read_yaml
from ccl_cli.learn import defaults as S

STAGES = ("learn-v", "learn-a", "learn-pi", "evaluate")
NUM = (int, float)

BASIS = {"kind": str, "n_centres": int, "centres": (str, list), "sigma2": NUM, "seed": int}
STREAM = {"topic": str, "field": str, "joints": list, "columns": list, "stamp": str,
          "dataset": str, "variable": str, "file": str, "samples": str}
ACTION = {**STREAM, "derive": str, "window": int, "order": int}
#: ``tune: {budget: seconds, folds: k}`` (or true/false) in a learner's section.
TUNE = {"budget": NUM, "folds": int, "max_rows": int}

SCHEMA: dict[str, Any] = {
    "seed": int,
    "data": {
        "files": (list, str), "format": str, "typestore": str, "state": STREAM, "action": ACTION,
        "time": {"column": (str, int), "unit": str, "rate": NUM, "delimiter": str,
                 "dataset": str, "variable": str, "file": str},
        "demos": {"split_on_gap": NUM, "ranges": list, "window": NUM, "per_file": bool,
                  "group": str, "dataset": str, "variable": str},
        "nonfinite": str, "min_samples": int,
        "test": {"fraction": NUM, "seed": int, "use_masks": bool, "gap": int, "min_demos": int,
                 "blocks": int},
    },
    "learn-v": {"basis": (str, BASIS), "n_centres": int, "max_iter": int, "tol": NUM, "tune": (bool, TUNE)},
    "learn-a": {
        "method": str, "on": str, "per_demo": bool, "selection": str, "n_constraints": int,
        "threshold": NUM, "gap_floor": NUM, "max_constraints": int, "cv_folds": int,
        "variant": str, "n_restarts": int, "max_iter": int, "tol": NUM,
        "basis": (str, BASIS), "n_centres": int,
        "features": (str, {"arm": str, "rows": list}),
        "regressors": str, "degree": int, "task": bool, "task_regressors": str, "whiten": str,
        "reweight": int, "tune": (bool, TUNE),
    },
    "learn-pi": {"method": str, "on": str, "basis": (str, BASIS), "n_centres": int, "cutoff": (NUM, str),
                 "cutoff_rule": str,
                 "min_norm": NUM, "projections": str, "baseline": bool, "tune": (bool, TUNE)},
    "evaluate": {"convention": str},
    "metrics": {"convention": str},
    "output": {"plots": bool},
    "stages": list,
}

DEFAULTS: dict[str, Any] = {
    "seed": 0,
    "data": {"format": "auto", "nonfinite": "drop", "test": {"fraction": 0.3, "seed": 0,
                                                             "use_masks": True}},
    "learn-v": {"basis": "rbf", "n_centres": 16, "tune": S.TUNE},
    "learn-a": {"method": "nhat", "on": "auto", "per_demo": False, "selection": S.DEFAULT_RULE,
                "tune": S.TUNE},
    "learn-pi": {"method": "pi", "on": "auto", "basis": "rbf", "n_centres": 16,
                 "projections": "auto", "baseline": True, "tune": S.TUNE},
    "metrics": {"convention": "ccl"},
    "output": {"plots": True},
}

CHOICES = {
    ("learn-a", "method"): ("nhat", "alpha", "lambda", "linear"),
    ("learn-a", "on"): ("auto", "u", "w"),
    ("learn-a", "selection"): ("ratio", "threshold", "eigengap", "cv"),
    ("learn-a", "variant"): ("closed_form", "search"),
    ("learn-a", "whiten"): ("rms", "errors", "none"),
    ("learn-pi", "method"): ("pi", "pi-weighted", "pi-coupled", "lwpi", "dpl"),
    ("learn-pi", "on"): ("auto", "u", "w"),
    ("learn-pi", "projections"): ("auto", "learnt", "true"),
    ("learn-pi", "cutoff_rule"): ("relative", "absolute"),
    ("metrics", "convention"): ("ccl", "original"),
    ("evaluate", "convention"): ("ccl", "original"),
    ("data", "format"): ("auto", "hdf5", "csv", "bag", "mcap", "mat"),
    ("data", "nonfinite"): ("drop", "fail"),
}

_TYPE_NAMES = {int: "an integer", float: "a number", str: "a string", bool: "true or false",
               list: "a list", dict: "a mapping"}


def _lines(node: yaml.Node, path: tuple = (), out: dict | None = None) -> dict[tuple, int]:
    """Line (1-based) of every key and list item of a composed YAML document."""
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


class Config(dict):
    """The config mapping, with ``source`` (file) and ``lines`` (path → line)."""

    source: str = "<flags>"
    lines: dict[tuple, int]
    base: Path | None = None
    flags: dict  # the command-line overrides merged in (see merge)

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.flags = {}


def load(path: str | Path | None) -> Config:
    """Read and validate a YAML config (``None`` → an empty config)."""
    cfg = Config()
    cfg.lines = {}
    if path is None:
        return cfg
    path = Path(path)
    data, node = read_yaml(path, "config")
    if data is None:
        data = {}
    if not isinstance(data, dict):
        raise ConfigError(f"{path}:1: the config must be a mapping of sections (data, learn-a, ...)")
    cfg.update(data)
    cfg.source = str(path)
    cfg.lines = _lines(node) if node is not None else {}
    cfg.base = path.parent
    validate(cfg)
    return cfg


def _where(cfg: Config, path: tuple) -> str:
    if cfg.source == FLAGS and path:
        return "--" + str(path[-1]).replace("_", "-")
    for cut in range(len(path), -1, -1):
        line = cfg.lines.get(path[:cut])
        if line is not None:
            return f"{cfg.source}:{line}"
    return cfg.source


def _dotted(path: tuple) -> str:
    return ".".join(str(p) if not isinstance(p, int) else f"[{p}]" for p in path).replace(".[", "[")


def _check(cfg: Config, value: Any, schema: Any, path: tuple) -> None:
    if isinstance(schema, tuple):  # alternatives: types and/or sub-schemas
        for alt in schema:
            if isinstance(alt, dict) and isinstance(value, dict):
                return _check(cfg, value, alt, path)
            if isinstance(alt, type) and _is(value, alt):
                return None
        names = " or ".join(_TYPE_NAMES.get(a, "a mapping") if isinstance(a, type) else "a mapping"
                            for a in schema)
        raise ConfigError(f"{_where(cfg, path)}: {_dotted(path)} must be {names}, got {value!r}")
    if isinstance(schema, dict):
        if not isinstance(value, dict):
            raise ConfigError(f"{_where(cfg, path)}: {_dotted(path)} must be a mapping, got {value!r}")
        for key, sub in value.items():
            if key not in schema:
                close = difflib.get_close_matches(str(key), list(schema), n=1)
                hint = f" (did you mean {close[0]!r}?)" if close else \
                    f" (valid: {', '.join(schema)})"
                where = f"in {_dotted(path)}" if path else "at the top level"
                raise ConfigError(f"{_where(cfg, (*path, key))}: unknown key {key!r} {where}{hint}")
            _check(cfg, sub, schema[key], (*path, key))
        return None
    if not _is(value, schema):
        raise ConfigError(f"{_where(cfg, path)}: {_dotted(path)} must be {_TYPE_NAMES[schema]}, "
                          f"got {value!r}")
    return None


def _is(value: Any, typ: type | tuple) -> bool:
    if typ is NUM or typ == (int, float):
        return isinstance(value, int | float) and not isinstance(value, bool)
    if typ is int:
        return isinstance(value, int) and not isinstance(value, bool)
    if typ is float:
        return isinstance(value, int | float) and not isinstance(value, bool)
    return isinstance(value, typ)


def validate(cfg: Config) -> None:
    """Check ``cfg`` against :data:`SCHEMA` and :data:`CHOICES` (raises ConfigError)."""
    _check(cfg, dict(cfg), {k: v for k, v in SCHEMA.items()}, ())
    for (section, key), allowed in CHOICES.items():
        value = (cfg.get(section) or {}).get(key)
        if value is not None and value not in allowed:
            close = difflib.get_close_matches(str(value), allowed, n=1)
            hint = f" (did you mean {close[0]!r}?)" if close else ""
            raise ConfigError(f"{_where(cfg, (section, key))}: {section}.{key} must be one of "
                              f"{', '.join(allowed)}, got {value!r}{hint}")
    for i, item in enumerate(cfg.get("stages") or []):
        name, options = stage_entry(item, cfg, i)
        _check(cfg, options, SCHEMA[name], ("stages", i, name))
    check_ranges(cfg, dict(cfg), ())


def stage_entry(item: Any, cfg: Config, i: int) -> tuple[str, dict]:
    """A ``stages`` item → (name, options)."""
    if isinstance(item, str):
        name, options = item, {}
    elif isinstance(item, dict) and len(item) == 1:
        name, options = next(iter(item.items()))
        options = options or {}
    else:
        raise ConfigError(f"{_where(cfg, ('stages', i))}: each stage is a name or a one-key mapping "
                          f"(e.g. - learn-a: {{method: nhat}}), got {item!r}")
    if name not in STAGES:
        close = difflib.get_close_matches(str(name), STAGES, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (stages: {', '.join(STAGES)})"
        raise ConfigError(f"{_where(cfg, ('stages', i))}: unknown stage {name!r}{hint}")
    return name, options


def deep_merge(base: dict, over: dict) -> dict:
    out = copy.deepcopy(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(out.get(key), dict):
            out[key] = deep_merge(out[key], value)
        else:
            out[key] = copy.deepcopy(value)
    return out


FLAGS = "command line"


def _override(opts: dict, flags: dict) -> dict:
    """``opts`` with a stage's flag values on top, at any depth: ``--n-centres`` also sets
    ``basis.n_centres`` and ``--basis KIND`` sets ``basis.kind`` when the basis is a mapping
    (so a flag is never shadowed by, nor wipes out, a basis mapping of the config); either
    flag switches the stage's basis search off (``tune: false``), so the given basis is used."""
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


def merge(cfg: Config, overrides: dict) -> Config:
    """``cfg`` with flag ``overrides`` (None values ignored) and defaults filled in;
    the result is validated again (flags are checked like file keys, and named as flags
    in errors). The flags are kept (``flags``) so :func:`stage_options` applies them over
    a ``stages`` item's own options too."""
    clean = _drop_none(overrides)
    if clean:
        check = Config(clean)
        check.source, check.lines = FLAGS, {}
        validate(check)
    merged_dict = deep_merge(DEFAULTS, dict(cfg))
    for key, value in clean.items():
        if key in STAGES and isinstance(value, dict):
            merged_dict[key] = _override(merged_dict.get(key) or {}, value)
        elif isinstance(value, dict) and isinstance(merged_dict.get(key), dict):
            merged_dict[key] = deep_merge(merged_dict[key], value)
        else:
            merged_dict[key] = copy.deepcopy(value)
    merged = Config(merged_dict)
    merged.source = cfg.source
    merged.lines = cfg.lines
    merged.base = cfg.base
    merged.flags = deep_merge(getattr(cfg, "flags", {}), clean)
    validate(merged)
    return merged


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


def stage_options(cfg: Config, name: str, extra: dict | None = None) -> dict:
    """Options of stage ``name``: its section, then the ``stages`` item's own options, then
    the command-line flags of that stage (flags win at any depth, see :func:`_override`)."""
    opts = deep_merge(cfg.get(name) or {}, extra or {})
    flags = (getattr(cfg, "flags", None) or {}).get(name)
    return _override(opts, flags) if flags else opts


#: allowed range (inclusive; None: unbounded) of numeric options, by key, wherever they
#: appear (stage sections, stages items, basis specs, data); every number must be finite
RANGES: dict[str, tuple[float | None, float | None]] = {
    "seed": (0, 2**63 - 1), "n_centres": (1, 100_000), "max_iter": (1, 10_000_000),
    "n_restarts": (1, 10_000), "window": (1, 1_000_000), "order": (1, 20), "min_samples": (1, None),
    "max_constraints": (1, 100_000), "n_constraints": (0, 100_000), "cv_folds": (2, 1000),
    "degree": (0, 10), "reweight": (0, 1000), "sigma2": (1e-300, None), "tol": (0, None),
    "rate": (1e-9, 1e12), "threshold": (0, None), "gap_floor": (0, None), "cutoff": (0, None),
    "min_norm": (0, None), "fraction": (0, 1), "max_rows": (100, None),
}


def check_ranges(cfg: Config, value: Any, path: tuple) -> None:
    """Numbers finite and, for the keys of :data:`RANGES`, within range (ConfigError)."""
    if isinstance(value, dict):
        for key, sub in value.items():
            check_ranges(cfg, sub, (*path, key))
    elif isinstance(value, list):
        for i, sub in enumerate(value):
            check_ranges(cfg, sub, (*path, i))
    elif isinstance(value, int | float) and not isinstance(value, bool):
        key = next((p for p in reversed(path) if isinstance(p, str)), "")
        lo, hi = RANGES.get(key, (None, None)) if path and path[-1] == key else (None, None)
        if isinstance(value, float) and value != value or value in (float("inf"), float("-inf")):
            raise ConfigError(f"{_where(cfg, path)}: {_dotted(path)} must be a finite number, got {value!r}")
        if (lo is not None and value < lo) or (hi is not None and value > hi):
            span = f"at least {lo:g}" if hi is None else f"between {lo:g} and {hi:g}"
            raise ConfigError(f"{_where(cfg, path)}: {_dotted(path)} must be {span}, got {value!r}"[:200])


def stage_list(cfg: Config, default: list[str] | None = None) -> list[tuple[str, dict]]:
    """The config's stages as (name, options) pairs (``default`` names when it has none)."""
    items = cfg.get("stages")
    if not items:
        if default is None:
            raise ConfigError(f"{cfg.source}: no stages to run (add a stages: list)")
        return [(name, {}) for name in default]
    return [stage_entry(item, cfg, i) for i, item in enumerate(items)]
