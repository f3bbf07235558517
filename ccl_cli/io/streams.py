"""What readers return: time-stamped numeric streams, and how to pick them from messages.

A :class:`Stream` is one selection from one file (a topic's field, or CSV columns):
``t_ns`` (n,) int64 nanoseconds and ``values`` (n, d) float64, with a name per column.
:class:`StreamSpec` says what to pick. :class:`FieldExtractor` turns decoded messages
(rosbags dataclasses, mcap ROS 1/ROS 2 objects or JSON dicts alike) into numbers.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from ccl_cli.errors import InputError

#: default field per message type (the part after the package, e.g. "JointState")
DEFAULT_FIELDS = {
    "JointState": "position",
    "PoseStamped": "pose.position",
    "TwistStamped": "twist.linear",
    "Float64MultiArray": "data",
    "Float32MultiArray": "data",
    "PointStamped": "point",
    "Vector3Stamped": "vector",
}
VECTOR_KEYS = ("x", "y", "z", "w")


@dataclass
class StreamSpec:
    """What to read: a ``topic`` (bags, MCAP) or ``columns`` (CSV, by name or index),
    a dotted ``field`` path to numbers, ``joints`` to select (JointState) and the
    time ``stamp`` source: ``header`` (header.stamp where present) or ``log``."""

    topic: str | None = None
    field: str | None = None
    joints: list[str] | None = None
    columns: list[str | int] | None = None
    stamp: str = "header"

    @classmethod
    def from_config(cls, value: dict[str, Any] | None) -> StreamSpec | None:
        if value is None:
            return None
        return cls(topic=value.get("topic"), field=value.get("field"), joints=value.get("joints"),
                   columns=value.get("columns"), stamp=value.get("stamp", "header"))

    def describe(self) -> str:
        if self.topic:
            return self.topic + (f" field {self.field}" if self.field else "")
        return f"columns {self.columns}"


@dataclass
class Stream:
    t_ns: np.ndarray
    values: np.ndarray
    names: list[str]
    source: str = ""
    meta: dict[str, Any] = field(default_factory=dict)


def short_type(msgtype: str) -> str:
    """'sensor_msgs/msg/JointState' or 'sensor_msgs/JointState' → 'JointState'."""
    return msgtype.replace("/msg/", "/").split("/")[-1]


def _get(obj: Any, key: str) -> Any:
    if isinstance(obj, dict):
        return obj[key]
    return getattr(obj, key)


def _has(obj: Any, key: str) -> bool:
    return key in obj if isinstance(obj, dict) else hasattr(obj, key)


def _fields_of(obj: Any) -> list[str]:
    if isinstance(obj, dict):
        return list(obj)
    if hasattr(obj, "__dataclass_fields__"):
        return list(obj.__dataclass_fields__)
    slots = getattr(type(obj), "__slots__", None)
    if slots:
        return [s for s in slots if not s.startswith("_")]
    return [k for k in vars(obj) if not k.startswith("_")] if hasattr(obj, "__dict__") else []


def flatten(obj: Any, prefix: str = "") -> tuple[list[float], list[str]]:
    """Numbers under ``obj`` in field order (Vector3/Point/Quaternion as x, y, z[, w])."""
    if isinstance(obj, bool):
        return [float(obj)], [prefix]
    if isinstance(obj, int | float | np.integer | np.floating):
        return [float(obj)], [prefix]
    if isinstance(obj, np.ndarray):
        flat = obj.ravel()
        if not np.issubdtype(flat.dtype, np.number):
            raise TypeError(prefix)
        return flat.astype(float).tolist(), [f"{prefix}[{i}]" for i in range(flat.size)]
    if isinstance(obj, list | tuple):
        vals, names = [], []
        for i, item in enumerate(obj):
            v, n = flatten(item, f"{prefix}[{i}]")
            vals += v
            names += n
        return vals, names
    if isinstance(obj, str | bytes) or obj is None:
        raise TypeError(prefix)
    keys = _fields_of(obj)
    if not keys:
        raise TypeError(prefix)
    vals, names = [], []
    for key in keys:
        try:
            v, n = flatten(_get(obj, key), f"{prefix}.{key}" if prefix else key)
        except TypeError:
            continue  # strings (frame_id) and the like are skipped in compound fields
        vals += v
        names += n
    if not vals:
        raise TypeError(prefix)
    return vals, names


def stamp_ns(stamp: Any) -> int:
    """ROS time (sec/nanosec, secs/nsecs, or a dict of those) → int nanoseconds."""
    for s_key, n_key in (("sec", "nanosec"), ("secs", "nsecs"), ("sec", "nsec")):
        if _has(stamp, s_key) and _has(stamp, n_key):
            return int(_get(stamp, s_key)) * 1_000_000_000 + int(_get(stamp, n_key))
    if hasattr(stamp, "to_nsec"):
        return int(stamp.to_nsec())
    raise TypeError("not a ROS time")


class FieldExtractor:
    """Pulls the numbers of one :class:`StreamSpec` out of decoded messages.

    Built for one topic; ``names`` are fixed by the first message. Raises
    :class:`InputError` naming the topic and field when the path is absent or
    not numeric.
    """

    def __init__(self, spec: StreamSpec, msgtype: str, where: str) -> None:
        self.spec = spec
        self.kind = short_type(msgtype)
        self.field = spec.field or DEFAULT_FIELDS.get(self.kind)
        if self.field is None:
            raise InputError(f"{where}: topic {spec.topic} has type {msgtype}; say which field "
                             "to read (e.g. field: pose.position)")
        self.path = self.field.split(".") if self.field else []
        self.where = where
        self.names: list[str] | None = None
        self._joint_cache: tuple[tuple[str, ...], np.ndarray] | None = None
        self.use_header = spec.stamp == "header"
        if spec.stamp not in ("header", "log"):
            raise InputError(f"{where}: stamp must be header or log, got {spec.stamp!r}")

    def _resolve(self, msg: Any) -> Any:
        obj = msg
        for i, key in enumerate(self.path):
            if not _has(obj, key):
                have = ", ".join(_fields_of(obj)) or "no fields"
                at = ".".join(self.path[:i]) or "the message"
                raise InputError(f"{self.where}: field {self.field!r} not found in {self.spec.topic} "
                                 f"({at} has: {have})")
            obj = _get(obj, key)
        return obj

    def values(self, msg: Any) -> list[float]:
        leaf = self._resolve(msg)
        if self.spec.joints is not None and self.kind == "JointState":
            return self._joints(msg, leaf)
        try:
            vals, names = flatten(leaf, self.field)
        except TypeError:
            raise InputError(f"{self.where}: field {self.field!r} of {self.spec.topic} is not numeric") \
                from None
        if self.names is None:
            self.names = names
        elif len(vals) != len(self.names):
            raise InputError(f"{self.where}: field {self.field!r} of {self.spec.topic} changes length "
                             f"({len(self.names)} → {len(vals)})")
        return vals

    def _joints(self, msg: Any, leaf: Any) -> list[float]:
        names = tuple(_get(msg, "name"))
        if self._joint_cache is None or self._joint_cache[0] != names:
            lookup = {n: i for i, n in enumerate(names)}
            missing = [j for j in self.spec.joints if j not in lookup]
            if missing:
                raise InputError(f"{self.where}: joint(s) {', '.join(missing)} not in {self.spec.topic} "
                                 f"(it has: {', '.join(names)})")
            self._joint_cache = (names, np.array([lookup[j] for j in self.spec.joints]))
            self.names = [f"{j}.{self.field}" for j in self.spec.joints]
        arr = np.asarray(leaf, dtype=float)
        if arr.size != len(names):
            raise InputError(f"{self.where}: {self.spec.topic} has {len(names)} joint names but "
                             f"{arr.size} values in {self.field!r}")
        return arr[self._joint_cache[1]].tolist()

    def time(self, msg: Any, log_time_ns: int) -> tuple[int, bool]:
        """(stamp in ns, whether it came from the header)."""
        if self.use_header and _has(msg, "header"):
            try:
                return stamp_ns(_get(_get(msg, "header"), "stamp")), True
            except (TypeError, AttributeError, KeyError):
                pass
        return int(log_time_ns), False


def collect(extractor: FieldExtractor, items, where: str, count: int | None = None) -> Stream:
    """Run ``extractor`` over ``(message, log_time_ns)`` pairs into a :class:`Stream`.

    When every header stamp is zero (never filled in) log time is used instead.
    """
    times: list[int] = []
    logs: list[int] = []
    rows: list[list[float]] = []
    from_header = False
    for msg, log_ns in items:
        t, hdr = extractor.time(msg, log_ns)
        from_header |= hdr
        times.append(t)
        logs.append(int(log_ns))
        rows.append(extractor.values(msg))
    if not rows:
        raise InputError(f"{where}: topic {extractor.spec.topic} has no messages")
    t_ns = np.asarray(times, dtype=np.int64)
    if from_header and not t_ns.any():
        t_ns, from_header = np.asarray(logs, dtype=np.int64), False
    values = np.asarray(rows, dtype=float)
    return Stream(t_ns, values, list(extractor.names or []), where,
                  {"topic": extractor.spec.topic, "field": extractor.field,
                   "stamp": "header" if from_header else "log"})
