"""The ``data`` section of a config as typed options: what to read and how.

``DataOptions`` holds the section (the app layer adds ``test``); its parts say what one
stream is (:class:`StreamOptions`: a topic and field of a bag or MCAP file, columns of a
CSV table, a dataset of an HDF5 file, a variable of a .mat file), how actions are made
(:class:`ActionOptions`: read as a stream, or derived from the state with a local
polynomial of ``window`` samples and degree ``order``), where time comes from
(:class:`TimeOptions`) and how a recording is cut into demonstrations
(:class:`DemoOptions`). The models are frozen pydantic v2 models; unknown keys and wrong
types are refused (strict: no string becomes a number), numbers must be finite.

Library users may pass a mapping: :meth:`DataOptions.from_mapping` validates it and turns
a failure into one :class:`~ccl_cli.errors.InputError` line naming the option.
"""

from __future__ import annotations

import difflib
import math
import types
import typing
from collections.abc import Mapping
from pathlib import Path
from typing import Any, Literal, Self

import numpy as np
from pydantic import BaseModel, ConfigDict, Field, ValidationError, field_validator, model_validator

from ccl_cli.errors import InputError
from ccl_cli.learn.params import Interval

Format = Literal["auto", "hdf5", "csv", "bag", "mcap", "mat"]
TimeUnit = Literal["s", "ms", "us", "ns"]
#: nanoseconds per time unit
UNIT_NS = {"s": 1_000_000_000, "ms": 1_000_000, "us": 1_000, "ns": 1}
#: a number as written (an integer stays one, so messages and metadata echo the config)
Number = int | float


class Options(BaseModel):
    """Common ground of the option models: frozen, strict, no unknown keys, finite numbers."""

    model_config = ConfigDict(extra="forbid", frozen=True, strict=True, allow_inf_nan=False, defer_build=True)

    def given(self) -> set[str]:
        """Names of the options that hold a value (not None)."""
        return {name for name in type(self).model_fields if getattr(self, name) is not None}

    @classmethod
    def from_mapping(cls, value: Self | Mapping[str, Any] | None, where: str = "", prefix: str = "data"
                     ) -> Self:
        """``value`` validated (an instance passes as is; None is the defaults). A failure is one
        :class:`InputError` line: ``where: prefix.key must be ..., got ...``."""
        if isinstance(value, cls):
            return value
        if value is None:
            return cls()
        if not isinstance(value, Mapping):
            raise InputError(_at(where, f"{prefix} must be a mapping, got {value!r}"[:200]))
        try:
            return cls.model_validate(_without_nones(cls, value))
        except ValidationError as exc:
            raise InputError(_at(where, describe_error(exc, cls, prefix))) from None


class ForwardKinematicsOptions(Options):
    """Task space from joint logs: the state's joint columns q mapped to the end-effector pose of
    ``frame`` of ``robot`` (a URDF / MJCF path, relative to the config, or ``{dh: [...]}``; see
    :func:`ccl_cli.learn.robots.load_robot`) from ``base``: positions x, y, z (m) and, with
    ``orientation``, unit quaternions qw, qx, qy, qz."""

    robot: str | dict[str, Any]
    frame: str | None = None
    base: str | None = None
    orientation: bool = False


class StreamOptions(Options):
    """One stream: a ``topic`` (bags, MCAP) with a dotted ``field`` path to numbers and the
    ``joints`` to pick (JointState), ``columns`` (CSV tables, HDF5 datasets, .mat variables:
    names or 0-based indices), a ``dataset`` (HDF5 layouts) or ``variable`` (.mat, dotted for
    struct fields); ``stamp``: header.stamp where present, or the log time; ``file``: a
    sibling text file holding this stream; ``samples``: which side of a matrix holds the
    samples (rows: one sample per row, as NumPy and HDF5 writers store them); ``units``: the
    unit of every dimension, or one list entry per dimension (shown in reports and figures;
    JointState fields and derived actions get theirs without it); ``forward_kinematics``:
    joint columns → end-effector pose (:class:`ForwardKinematicsOptions`)."""

    topic: str | None = None
    field: str | None = None
    joints: list[str] | None = None
    columns: list[int | str] | None = Field(None, description="a list of column names or 0-based indices")
    stamp: Literal["header", "log"] = "header"
    dataset: str | None = None
    variable: str | None = None
    file: str | None = None
    samples: Literal["rows", "columns"] | None = None
    units: str | list[str] | None = Field(None, description="a unit, or a list of one per dimension")
    forward_kinematics: ForwardKinematicsOptions | None = None

    def describe(self) -> str:
        """'/joint_states field position', or 'columns [...]' (for messages)."""
        if self.topic:
            return self.topic + (f" field {self.field}" if self.field else "")
        if self.variable or self.dataset:
            return str(self.variable or self.dataset)
        return f"columns {self.columns}"


class SignalOptions(StreamOptions):
    """A signal that cuts demonstrations (``demos.where``): a stream as :class:`StreamOptions`
    names it (``column``: one CSV column) and a level on its Euclidean norm per sample —
    kept where the norm is above ``norm_above`` and/or below ``norm_below``."""

    column: int | str | None = None
    norm_above: Number | None = None
    norm_below: Number | None = None

    @model_validator(mode="after")
    def _a_level(self) -> SignalOptions:
        if self.norm_above is None and self.norm_below is None:
            raise ValueError("needs a level: norm_above and/or norm_below")
        return self

    def selection(self) -> StreamOptions:
        """The stream to read (``column`` as a one-item ``columns``)."""
        keep = {k: getattr(self, k) for k in StreamOptions.model_fields if getattr(self, k) is not None}
        if self.column is not None:
            keep["columns"] = [self.column]
        return StreamOptions(**keep)

    def passes(self, values: np.ndarray) -> np.ndarray:
        """Samples (N, d) → (N,) bool: the norm is within the levels (NaN never passes)."""
        norm = np.linalg.norm(np.atleast_2d(values.T).T, axis=1)
        ok = np.isfinite(norm)
        if self.norm_above is not None:
            ok &= norm > self.norm_above
        if self.norm_below is not None:
            ok &= norm < self.norm_below
        return ok


class ActionOptions(StreamOptions):
    """The action: a stream, or ``derive: state`` — dX/dt by a local polynomial of degree
    ``order`` fitted to ``window`` samples (odd; default: from the sampling rate)."""

    derive: Literal["state"] | None = None
    window: int | None = Field(None, **Interval(1, 1_000_000, type=int).field())
    order: int = Field(2, **Interval(1, 20, type=int).field())


class OrientationOptions(StreamOptions):
    """The tool's orientation at each sample, a unit quaternion (4 numbers), named as a stream
    is (:class:`StreamOptions`), in ``convention`` wxyz (scalar first) or xyzw (scalar last,
    as ROS ``geometry_msgs/Quaternion`` fields are laid out: the default for a topic)."""

    convention: Literal["wxyz", "xyzw"] | None = None


class ForceOptions(StreamOptions):
    """A force/torque sensor's force channel (3 numbers per sample, fx fy fz), named as a stream
    is (:class:`StreamOptions`), in ``frame`` base (the frame of the states' positions, the
    default) or tool — then ``orientation`` (:class:`OrientationOptions`) rotates it into the
    base frame: f_base = R(q) f_tool."""

    frame: Literal["base", "tool"] = "base"
    orientation: OrientationOptions | None = None

    @model_validator(mode="after")
    def _frame(self) -> ForceOptions:
        if self.frame == "tool" and self.orientation is None:
            raise ValueError("frame: tool needs orientation: the tool's quaternion stream (e.g. {columns: "
                             "[3, 4, 5, 6], convention: wxyz}) to rotate the force into the base frame")
        if self.frame == "base" and self.orientation is not None:
            raise ValueError("orientation applies to frame: tool (a base-frame force is not rotated)")
        if self.forward_kinematics is not None:
            raise ValueError("forward_kinematics applies to the state, not to a force")
        return self


class TimeOptions(Options):
    """Where time comes from: a CSV ``column`` (name or index), an HDF5 ``dataset`` or a .mat
    ``variable``, in ``unit`` (integer stamps without one: ≥ 1e15 means ns, else s), or a
    sampling ``rate`` in Hz. ``delimiter``: a CSV's separator (one character, or
    ``whitespace``), sniffed when not given."""

    column: int | str | None = Field(None, description="a column name or a 0-based index")
    unit: TimeUnit | None = None
    rate: Number | None = Field(None, **Interval(1e-9, 1e12).field("Hz"))
    delimiter: str | None = None
    dataset: str | None = None
    variable: str | None = None
    file: str | None = None

    @field_validator("delimiter")
    @classmethod
    def _one_character(cls, value: str | None) -> str | None:
        if value is None or value == "whitespace":
            return value
        if len(value) != 1 or value in "\r\n\"" or value.isalnum():
            raise ValueError("must be one character (or whitespace)")
        return value


#: A length of time > 0 (seconds).
_SECONDS = Interval(0, None, closed="neither")


class DemoOptions(Options):
    """How a recording becomes demonstrations (:mod:`ccl_cli.io.segment`). Every format:
    ``split_on_gap`` (a pause longer than this many seconds starts a new one), ``ranges``
    (a list of [start, end] seconds from the file's first sample, or per demonstration
    ``{index: [[start, end], ...]}`` in seconds from that demonstration's first sample, the
    index counting within each file;
    samples outside every range are dropped), ``where`` (a :class:`SignalOptions`: each
    stretch where the signal's norm passes its level is a demonstration), ``min_duration``
    (shorter pieces dropped), ``window`` (then fixed pieces of this many seconds). HDF5
    layouts: one per ``group`` matching a glob, or a ``dataset`` holding a demo id per
    sample; .mat: a demo-index ``variable``."""

    split_on_gap: Number | None = Field(None, **_SECONDS.field("s"))
    ranges: list[list[Number]] | dict[int, list[list[Number]]] | None = Field(
        None, description="a list of [start, end] pairs or {demo index: [[start, end], ...]}")
    where: SignalOptions | None = None
    min_duration: Number | None = Field(None, **Interval(0, None).field("s"))
    window: Number | None = Field(None, **_SECONDS.field("s"))
    per_file: bool | None = None
    group: str | None = None
    dataset: str | None = None
    variable: str | None = None

    @field_validator("ranges", mode="before")
    @classmethod
    def _pairs(cls, value: Any) -> Any:
        """Each range two finite numbers, start < end (checked before the types, so a range
        that is not a pair is named as a whole); per demonstration, keys are indices ≥ 0
        (written as integers or digit strings)."""
        if value is None:
            return value
        if isinstance(value, Mapping):
            out = {}
            for key, pairs in value.items():
                index = int(key) if isinstance(key, str) and key.isdigit() else key
                if isinstance(index, bool) or not isinstance(index, int) or index < 0:
                    raise ValueError(f"keys must be demonstration indices (0, 1, ...), got {key!r}")
                out[index] = _range_list(pairs, f"[{index}]")
            return out
        return _range_list(value, "")


def _range_list(value: Any, at: str) -> list[list[Any]]:
    """``value`` checked as a list of [start, end] pairs of finite seconds, start < end."""
    if not isinstance(value, list | tuple):
        raise ValueError(f"{at} must be a list of [start, end] pairs".lstrip())
    for k, pair in enumerate(value):
        numbers = isinstance(pair, list | tuple) and len(pair) == 2 and all(
            isinstance(v, int | float) and not isinstance(v, bool) and math.isfinite(v) for v in pair)
        if not numbers or not pair[0] < pair[1]:
            raise ValueError(f"{at}[{k}] must be [start, end] (finite seconds) with start < end, "
                             f"got {pair!r}")
    return [list(pair) for pair in value]


class FaultOptions(Options):
    """What the readers do with sensor faults in a recording's states (:mod:`ccl_cli.io.faults`,
    before velocities are derived): hemisphere ``flips`` of a magnetic tracker mirrored back,
    dropped or kept; ``spikes`` (isolated outliers) dropped or kept; ``stamps`` (duplicated
    samples, repeated or out-of-order stamps, clock steps) repaired or kept. Whatever is found
    is reported, with its count and time ranges."""

    flips: Literal["mirror", "drop", "keep"] = "mirror"
    spikes: Literal["drop", "keep"] = "drop"
    stamps: Literal["repair", "keep"] = "repair"


class DataOptions(Options):
    """The ``data`` section: ``files`` (paths or globs), the ``format`` (auto: from the
    content), the ``state`` stream, the ``action`` (a stream, or derived from the state when
    absent), a ``force`` channel (:class:`ForceOptions`, optional), ``time``, ``demos``, what
    to do with samples holding NaN or inf (``nonfinite``),
    with sensor ``faults``, the ``typestore`` of ROS 2 bags without message definitions, the
    fewest samples a dataset may have (``min_samples``), and whether the files a ROS 2 bag's
    metadata names may lie outside its folder (``allow_outside``; symlinks resolved)."""

    files: str | Path | list[str | Path] | None = Field(None, description="a path or a list of paths")
    format: Format = "auto"
    typestore: str | None = None
    state: StreamOptions | None = None
    action: ActionOptions | None = None
    force: ForceOptions | None = None
    time: TimeOptions = TimeOptions()
    demos: DemoOptions = DemoOptions()
    nonfinite: Literal["drop", "fail"] = "drop"
    faults: FaultOptions = FaultOptions()
    min_samples: int = Field(2, **Interval(1, None, type=int).field())
    allow_outside: bool = False

    @classmethod
    def from_mapping(cls, value: Self | Mapping[str, Any] | None, where: str = "", prefix: str = "data"
                     ) -> Self:
        """As :meth:`Options.from_mapping`; a ``test`` key (the app layer's) is left out."""
        if isinstance(value, Mapping) and "test" in value:
            value = {k: v for k, v in value.items() if k != "test"}
        return super().from_mapping(value, where, prefix)

    @property
    def derives_action(self) -> bool:
        """True when the action is dX/dt of the state (no action, ``derive: state``, or an
        action section that names nothing)."""
        return self.action is None or self.action.derive is not None or not self.action.model_fields_set


# -- one-line messages -----------------------------------------------------------------------
_PHRASES = {
    "int_type": "an integer", "float_type": "a number", "string_type": "a string",
    "bool_type": "true or false", "list_type": "a list", "model_type": "a mapping", "dict_type": "a mapping",
    "finite_number": "a finite number", "is_instance_of": "a path",
}


def _at(where: str, message: str) -> str:
    return f"{where}: {message}" if where else message


def _without_nones(cls: type[Options], value: Mapping[str, Any]) -> dict[str, Any]:
    """A key given as None (YAML ``time:`` with nothing after it) counts as absent when its
    option is a section (a mapping) or has a default that is not None."""
    out = {}
    for key, item in value.items():
        info = cls.model_fields.get(key) if isinstance(key, str) else None
        if item is None and info is not None and info.default is not None:
            continue
        out[key] = item
    return out


def _model_in(annotation: Any) -> type[Options] | None:
    """The option model inside an annotation (``X``, ``X | None``), if any."""
    if isinstance(annotation, type) and issubclass(annotation, Options):
        return annotation
    if isinstance(annotation, types.UnionType) or typing.get_origin(annotation) is typing.Union:
        for arg in typing.get_args(annotation):
            found = _model_in(arg)
            if found is not None:
                return found
    return None


def describe_error(exc: ValidationError, model: type[Options], prefix: str = "data") -> str:
    """The first error of ``exc`` as one line: ``prefix.key must be ..., got ...``, or
    ``prefix: unknown option 'key' (did you mean ...?)``."""
    errors = exc.errors(include_url=False)
    err = errors[0]
    path, description, cls, key, consumed = prefix, None, model, None, 0
    for part in err["loc"]:
        if isinstance(part, int):
            path, description = f"{path}[{part}]", None
        elif cls is not None and part in cls.model_fields:
            info = cls.model_fields[part]
            path, description, cls, key = f"{path}.{part}", info.description, _model_in(info.annotation), part
        else:
            key = part  # an unknown key, or a member of a union (e.g. 'str' of str | int)
            break
        consumed += 1
    if err["type"] == "extra_forbidden":
        valid = list(cls.model_fields) if cls is not None else []
        close = difflib.get_close_matches(str(key), valid, n=1)
        hint = f" (did you mean {close[0]!r}?)" if close else f" (valid: {', '.join(valid)})"
        what = "unknown data option" if path == prefix == "data" else f"{path}: unknown option"
        return f"{what} {key!r}{hint}"[:300]
    got = f", got {err['input']!r}"
    if err["type"] == "value_error":
        text = str(err["ctx"]["error"])
        return f"{path}{'' if text.startswith('[') else ' '}{text}{'' if 'got ' in text else got}"[:300]
    if err["type"] == "literal_error":
        return f"{path} must be {err['ctx']['expected']}{got}"[:300]
    if description is None:
        base = err["loc"][:consumed]  # every member of a union failed here: name them all
        kinds = [_phrase(e) for e in errors if e["loc"][:consumed] == base]
        kinds = ["a number" if k in ("an integer", "a number") and "a number" in kinds else k for k in kinds]
        description = " or ".join(dict.fromkeys(kinds))
    return f"{path} must be {description}{got}"[:300]


def _phrase(err: Any) -> str:
    """What one pydantic error says the value must be."""
    if err["type"] in ("greater_than", "greater_than_equal", "less_than_equal"):
        bound = next(iter(err["ctx"].values()))
        sign = {"greater_than": "greater than", "greater_than_equal": "at least"}.get(err["type"], "at most")
        return f"{sign} {bound:g}" if isinstance(bound, float) and math.isfinite(bound) else f"{sign} {bound}"
    return _PHRASES.get(err["type"]) or err["msg"][0].lower() + err["msg"][1:]
