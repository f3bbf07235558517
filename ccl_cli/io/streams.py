"""What readers return: time-stamped numeric streams, and how to pick them from messages.

A :class:`Stream` is one selection from one file (a topic's field, or CSV columns):
``t_ns`` (n,) int64 nanoseconds and ``values`` (n, d) float64, with a name per column.
:class:`StreamSpec` says what to pick. :class:`FieldExtractor` turns decoded messages
(rosbags dataclasses, mcap ROS 1/ROS 2 objects or JSON dicts alike) into numbers.
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from operator import attrgetter
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


def _getter(path: list[str], sample: Any) -> Callable[[Any], Any]:
    """A compiled accessor for a dotted path on messages shaped like ``sample``."""
    if not path:
        return lambda m: m
    if isinstance(sample, dict):
        def get(m: Any) -> Any:
            for key in path:
                m = m[key]
            return m

        return get
    return attrgetter(".".join(path))


class FieldExtractor:
    """Pulls the numbers of one :class:`StreamSpec` out of decoded messages.

    Built for one topic. The first message fixes the column names and compiles the
    accessors (attribute/key getters, joint index map); later messages take the fast
    path. Raises :class:`InputError` naming the topic and field when the path is
    absent or not numeric.
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
        self._get: Callable[[Any], Any] | None = None
        self._fast: Callable[[Any], Any] | None = None
        self._joint_names: list[str] | None = None
        self._joint_index: np.ndarray | None = None
        self._joint_identity = False
        if spec.stamp not in ("header", "log"):
            raise InputError(f"{where}: stamp must be header or log, got {spec.stamp!r}")

    def _resolve(self, msg: Any) -> Any:
        """Slow, checked walk of the path (first message, and to explain failures)."""
        obj = msg
        for i, key in enumerate(self.path):
            if not _has(obj, key):
                have = ", ".join(_fields_of(obj)) or "no fields"
                at = ".".join(self.path[:i]) or "the message"
                raise InputError(f"{self.where}: field {self.field!r} not found in {self.spec.topic} "
                                 f"({at} has: {have})")
            obj = _get(obj, key)
        return obj

    def _first(self, msg: Any, leaf: Any) -> list[float] | np.ndarray:
        try:
            vals, names = flatten(leaf, self.field)
        except TypeError:
            raise InputError(f"{self.where}: field {self.field!r} of {self.spec.topic} is not numeric") \
                from None
        self.names = names
        if isinstance(leaf, np.ndarray | list | tuple) and all(
                isinstance(v, int | float | np.number) for v in np.asarray(leaf).ravel()[:1]):
            self._fast = lambda x: x  # numeric sequence: assign as is
        elif not isinstance(leaf, dict) and all(hasattr(leaf, k) for k in VECTOR_KEYS[:3]) \
                and len(vals) in (3, 4):
            self._fast = attrgetter(*VECTOR_KEYS[: len(vals)])
        return vals

    def values(self, msg: Any) -> list[float] | np.ndarray:
        if self._get is None:
            self._get = _getter(self.path, msg)
            leaf = self._resolve(msg)
        else:
            try:
                leaf = self._get(msg)
            except (AttributeError, KeyError, TypeError):
                leaf = self._resolve(msg)
        if self.spec.joints is not None and self.kind == "JointState":
            return self._joints(msg, leaf)
        if self.names is None:
            return self._first(msg, leaf)
        if self._fast is not None:
            vals = self._fast(leaf)
            if len(vals) == len(self.names):
                return vals
        try:
            vals, _ = flatten(leaf, self.field)
        except TypeError:
            raise InputError(f"{self.where}: field {self.field!r} of {self.spec.topic} is not numeric") \
                from None
        if len(vals) != len(self.names):
            raise InputError(f"{self.where}: field {self.field!r} of {self.spec.topic} changes length "
                             f"({len(self.names)} → {len(vals)})")
        return vals

    def _joints(self, msg: Any, leaf: Any) -> np.ndarray | Any:
        names = _get(msg, "name")
        if names != self._joint_names:  # list equality: cheap, and robust to reordering
            names = list(names)
            lookup = {n: i for i, n in enumerate(names)}
            missing = [j for j in self.spec.joints if j not in lookup]
            if missing:
                raise InputError(f"{self.where}: joint(s) {', '.join(missing)} not in {self.spec.topic} "
                                 f"(it has: {', '.join(names)})")
            self._joint_names = names
            self._joint_index = np.array([lookup[j] for j in self.spec.joints])
            self._joint_identity = len(names) == len(self.spec.joints) and \
                bool((self._joint_index == np.arange(len(names))).all())
            self.names = [f"{j}.{self.field}" for j in self.spec.joints]
        if len(leaf) != len(names):
            raise InputError(f"{self.where}: {self.spec.topic} has {len(names)} joint names but "
                             f"{len(leaf)} values in {self.field!r}")
        if self._joint_identity:
            return leaf
        return np.asarray(leaf, dtype=float)[self._joint_index]


class StampReader:
    """Time of each message: header.stamp (compiled on the first message) or log time."""

    def __init__(self, use_header: bool) -> None:
        self.use_header = use_header
        self._get: Callable[[Any], tuple[int, int]] | None = None
        self._checked = False

    def __call__(self, msg: Any, log_ns: int) -> tuple[int, bool]:
        if self.use_header:
            if not self._checked:
                self._checked = True
                self._get = self._compile(msg)
            if self._get is not None:
                sec, nsec = self._get(msg)
                return int(sec) * 1_000_000_000 + int(nsec), True
        return int(log_ns), False

    @staticmethod
    def _compile(msg: Any) -> Callable[[Any], tuple[int, int]] | None:
        if not _has(msg, "header"):
            return None
        stamp = _get(_get(msg, "header"), "stamp")
        for s_key, n_key in (("sec", "nanosec"), ("secs", "nsecs"), ("sec", "nsec")):
            if _has(stamp, s_key) and _has(stamp, n_key):
                if isinstance(msg, dict):
                    return lambda m, a=s_key, b=n_key: (m["header"]["stamp"][a], m["header"]["stamp"][b])
                return attrgetter(f"header.stamp.{s_key}", f"header.stamp.{n_key}")
        return None


class Collector:
    """Accumulates one stream. Rows, stamps and log times are appended to Python lists
    and converted to NumPy once per ``BLOCK`` messages, so the per-message cost is a few
    list appends and memory stays near the size of the final arrays.

    When every header stamp is zero (never filled in) log time is used instead.
    """

    BLOCK = 4096

    def __init__(self, extractor: FieldExtractor, where: str, capacity: int = 0) -> None:
        self.extractor = extractor
        self.where = where
        self.stamp = StampReader(extractor.spec.stamp == "header")
        self.n = 0
        self.from_header = False
        self._rows: list[Any] = []
        self._t: list[int] = []
        self._log: list[int] = []
        self._blocks: list[tuple[np.ndarray, np.ndarray, np.ndarray]] = []

    def add(self, msg: Any, log_ns: int, stamp: tuple[int, bool] | None = None) -> None:
        """Append one message; ``stamp`` (from a shared :class:`StampReader`) saves the lookup."""
        t, hdr = stamp if stamp is not None else self.stamp(msg, log_ns)
        self._rows.append(self.extractor.values(msg))
        self._t.append(t)
        self._log.append(log_ns)
        self.from_header |= hdr
        if len(self._rows) >= self.BLOCK:
            self._flush()

    def _flush(self) -> None:
        if not self._rows:
            return
        try:
            rows = np.array(self._rows, dtype=float)
        except ValueError:
            raise InputError(f"{self.where}: field {self.extractor.field!r} of {self.extractor.spec.topic} "
                             "changes length between messages") from None
        if rows.ndim != 2:
            rows = rows.reshape(len(self._rows), -1)
        self._blocks.append((np.array(self._t, dtype=np.int64), np.array(self._log, dtype=np.int64), rows))
        self.n += len(self._rows)
        self._rows, self._t, self._log = [], [], []

    def finish(self, sort_by_log_time: bool = False) -> Stream:
        """The stream; ``sort_by_log_time`` restores log-time order (stable) when the
        messages were read in file order."""
        self._flush()
        spec = self.extractor.spec
        if self.n == 0:
            raise InputError(f"{self.where}: topic {spec.topic} has no messages")
        widths = {b[2].shape[1] for b in self._blocks}
        if len(widths) > 1:
            raise InputError(f"{self.where}: field {self.extractor.field!r} of {spec.topic} changes length "
                             "between messages")
        t_ns = np.concatenate([b[0] for b in self._blocks])
        log = np.concatenate([b[1] for b in self._blocks])
        values = np.concatenate([b[2] for b in self._blocks])
        self._blocks = []
        if sort_by_log_time and self.n > 1 and (np.diff(log) < 0).any():
            order = np.argsort(log, kind="stable")
            t_ns, log, values = t_ns[order], log[order], values[order]
        from_header = self.from_header
        if from_header and not t_ns.any():
            t_ns, from_header = log, False
        return Stream(t_ns, values, list(self.extractor.names or []), self.where,
                      {"topic": spec.topic, "field": self.extractor.field,
                       "stamp": "header" if from_header else "log"})


def feed(group: list[Collector], msg: Any, log_ns: int) -> None:
    """Give one message to every collector of its topic; the stamp is read once."""
    first = group[0]
    stamp = first.stamp(msg, log_ns)
    first.add(msg, log_ns, stamp)
    for col in group[1:]:
        col.add(msg, log_ns, stamp if col.stamp.use_header == first.stamp.use_header else None)
