"""Numbers out of decoded ROS messages: one topic's fields → :class:`~ccl_cli.io.streams.Stream`.

:class:`FieldExtractor` turns decoded messages (rosbags dataclasses, mcap ROS 1/ROS 2
objects or JSON dicts alike) into numbers for one :class:`~ccl_cli.io.options.StreamOptions`;
:class:`TopicCollector` gathers every stream of one topic, message by message, into arrays.
Bags and MCAP files share them, and the topic listing of ``ccl inspect``
(:func:`describe_topics`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Callable
from operator import attrgetter
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.options import StreamOptions
from ccl_cli.io.streams import Stream, StreamReader
from ccl_cli.io.summary import activity

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


def type_name(msgtype: str) -> str:
    """A message type named one way whatever the container: 'package/msg/Type', as ROS 2 and
    rosbags name it (a ROS 1 bag's or a ROS 1 MCAP's 'sensor_msgs/JointState' →
    'sensor_msgs/msg/JointState'); any other name as it is."""
    parts = msgtype.split("/")
    return "/".join([parts[0], "msg", parts[1]]) if len(parts) == 2 and all(parts) else msgtype


def short_type(msgtype: str) -> str:
    """'sensor_msgs/msg/JointState' or 'sensor_msgs/JointState' → 'JointState'."""
    return msgtype.replace("/msg/", "/").split("/")[-1]


def _get(obj: Any, key: str) -> Any:
    if isinstance(obj, dict):
        return obj[key]
    return getattr(obj, key)


def _has(obj: Any, key: str) -> bool:
    return key in obj if isinstance(obj, dict) else hasattr(obj, key)


def _fields_of(obj: Any, declared: bool = False) -> list[str]:
    """Field names of a message (``declared``: a dataclass's fields without its ClassVars)."""
    if isinstance(obj, dict):
        return list(obj)
    if hasattr(obj, "__dataclass_fields__"):
        return [f.name for f in dataclasses.fields(obj)] if declared else list(obj.__dataclass_fields__)
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
    """Pulls the numbers of one :class:`StreamOptions` out of decoded messages.

    Built for one topic. The first message fixes the column names and compiles the
    accessors (attribute/key getters, joint index map); later messages take the fast
    path. Raises :class:`InputError` naming the topic and field when the path is
    absent or not numeric.
    """

    def __init__(self, spec: StreamOptions, msgtype: str, where: str) -> None:
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
        self._wanted: list[str] | None = list(spec.joints) if spec.joints is not None else None

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
        if not names:
            raise InputError(f"{self.where}: field {self.field!r} of {self.spec.topic} is empty (no values "
                             "in its first message)")
        self.names = names
        if isinstance(leaf, np.ndarray | list | tuple) and all(
                isinstance(v, int | float | np.number) for v in np.asarray(leaf).ravel()[:1]):
            self._fast = _identity  # numeric sequence: assign as is
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
        if self.kind == "JointState" and self._by_joint(msg, leaf):
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

    @property
    def by_joint(self) -> bool:
        """Read joint by joint (decided by the first message: :meth:`_by_joint`)."""
        return self.kind == "JointState" and bool(self._wanted)

    def _by_joint(self, msg: Any, leaf: Any) -> bool:
        """Whether this JointState field is read joint by joint: the configured ``joints``,
        else the joints the first message names (so columns are named ``<joint>.<field>``
        and follow the joints if later messages reorder them). A message without joint
        names (or a field that is not one value per joint) is read by position."""
        if self._wanted is None and self.names is None:
            names = _get(msg, "name") if _has(msg, "name") else None
            per_joint = isinstance(leaf, list | tuple | np.ndarray) and isinstance(names, list | tuple) \
                and len(names) == len(leaf) > 0 and all(isinstance(n, str) for n in names) \
                and len(set(names)) == len(names)
            self._wanted = list(names) if per_joint else []
        return bool(self._wanted)

    def _joints(self, msg: Any, leaf: Any) -> np.ndarray | Any:
        names = _get(msg, "name") if _has(msg, "name") else None
        if names is None or names != self._joint_names:  # list equality: cheap, robust to reordering
            if not isinstance(names, list | tuple) or not all(isinstance(n, str) for n in names):
                raise InputError(f"{self.where}: {self.spec.topic}: a JointState needs name: a list of "
                                 f"strings, got {type(names).__name__}")
            if not isinstance(leaf, list | tuple | np.ndarray):
                raise InputError(f"{self.where}: field {self.field!r} of {self.spec.topic} must be a list "
                                 f"of numbers, got {type(leaf).__name__}")
            names = list(names)
            lookup = {n: i for i, n in enumerate(names)}
            missing = [j for j in self._wanted if j not in lookup]
            if missing:
                raise InputError(f"{self.where}: joint(s) {', '.join(missing)} not in {self.spec.topic} "
                                 f"(it has: {', '.join(names)})")
            self._joint_names = names
            self._joint_index = np.array([lookup[j] for j in self._wanted])
            self._joint_identity = len(names) == len(self._wanted) and \
                bool((self._joint_index == np.arange(len(names))).all())
            self.names = [f"{j}.{self.field}" for j in self._wanted]
        if len(leaf) != len(names):
            raise InputError(f"{self.where}: {self.spec.topic} has {len(names)} joint names but "
                             f"{len(leaf)} values in {self.field!r}")
        if self._joint_identity:
            return leaf
        return np.asarray(leaf, dtype=float)[self._joint_index]


class TopicCollector:
    """Accumulates every stream read from one topic, one call per message.

    The first message (and any message whose joint-name order differs from the current
    block's) goes through the checked path of each :class:`FieldExtractor`; the others
    take a compiled fast path: C-level attribute getters for every selected field, the
    raw ``(sec, nsec)`` header stamp and the log time appended to Python lists. Once per
    ``BLOCK`` messages (and whenever the joint order changes) the lists become NumPy
    arrays; joint reordering, stamp arithmetic and shape checks happen there, vectorised.
    When every header stamp is zero (never filled in) log time is used instead.
    """

    BLOCK = 4096

    def __init__(self, extractors: list[FieldExtractor], where: str) -> None:
        self.extractors = extractors
        self.where = where
        self.topic = extractors[0].spec.topic
        self.use_header = any(e.spec.stamp == "header" for e in extractors)
        self._stamp: Callable[[Any], tuple[int, int]] | None = None
        self._compiled = False
        self._getters: list[Callable[[Any], Any]] = []
        self._index: list[np.ndarray | None] = []
        self._names: Any = None
        self._name_of: Callable[[Any], Any] | None = None
        self._rows: list[list[Any]] = [[] for _ in extractors]
        self._stamps: list[Any] = []
        self._logs: list[int] = []
        self._blocks: list[list[np.ndarray]] = [[] for _ in extractors]
        self._tblocks: list[np.ndarray] = []
        self._lblocks: list[np.ndarray] = []
        self._header_seen = False

    # -- per message -------------------------------------------------------------------
    def add(self, msg: Any, log_ns: int) -> None:
        try:
            if not self._compiled or (self._name_of is not None and self._name_of(msg) != self._names):
                self._checked(msg)
            for rows, get in zip(self._rows, self._getters, strict=True):
                rows.append(get(msg))
            self._stamps.append(self._stamp(msg) if self._stamp is not None else (0, 0))
        except (KeyError, AttributeError, TypeError, IndexError) as exc:
            # a message shaped unlike the first (a JSON message missing a key, a field of
            # another type): named here, not left to the caller
            raise self._misshapen(msg, exc) from None
        self._logs.append(log_ns)
        if len(self._logs) >= self.BLOCK:
            self._flush()

    def _misshapen(self, msg: Any, exc: Exception) -> InputError:
        """The one-line error for a message the compiled path cannot read: the extractors'
        own explanation when they have one, else the missing key or attribute."""
        n = self.n_messages + 1
        try:
            for ex in self.extractors:
                ex.values(msg)
        except InputError as err:
            return InputError(f"{err.message} (message {n})")
        except (KeyError, AttributeError, TypeError, IndexError) as err:
            exc = err
        what = f"has no {exc.args[0]!r}" if isinstance(exc, KeyError) and exc.args else \
            f"cannot be read ({type(exc).__name__}: {str(exc)[:80]})"
        stamp = " (header.stamp)" if self._stamp is not None else ""
        return InputError(f"{self.where}: message {n} of {self.topic} {what}{stamp}; every message needs "
                          "the fields of the first")

    @property
    def n_messages(self) -> int:
        """Messages added so far."""
        return sum(len(b) for b in self._lblocks) + len(self._logs)

    def _checked(self, msg: Any) -> None:
        """Validate ``msg`` with the extractors and (re)compile the fast path."""
        self._flush()
        for ex in self.extractors:
            ex.values(msg)  # raises a precise InputError on a bad path, type or joint set
        if not self._compiled:
            self._stamp = _stamp_getter(msg) if self.use_header else None
            self._header_seen = self._stamp is not None
        self._getters, self._index = [], []
        self._name_of = None
        for ex in self.extractors:
            if ex.by_joint:
                get = ex._get
                self._index.append(None if ex._joint_identity else ex._joint_index)
                self._name_of = _getter(["name"], msg)
                self._names = list(self._name_of(msg))
            elif ex._fast is not None:
                field_get, fast = ex._get, ex._fast
                get = field_get if fast is _identity else (lambda m, g=field_get, f=fast: f(g(m)))
                self._index.append(None)
            else:
                get = ex.values  # compound fields: the general (slower) path
                self._index.append(None)
            self._getters.append(get)
        self._compiled = True

    # -- per block ---------------------------------------------------------------------
    def _flush(self) -> None:
        n = len(self._logs)
        if n == 0:
            return
        for k, ex in enumerate(self.extractors):
            try:
                rows = np.array(self._rows[k], dtype=float)
            except (ValueError, TypeError):
                raise InputError(f"{self.where}: field {ex.field!r} of {self.topic} changes length "
                                 "between messages") from None
            rows = rows.reshape(n, -1)
            if ex.by_joint and self._names is not None:
                if rows.shape[1] != len(self._names):
                    raise InputError(f"{self.where}: {self.topic} has {len(self._names)} joint names but "
                                     f"{rows.shape[1]} values in {ex.field!r}")
                if self._index[k] is not None:
                    rows = rows[:, self._index[k]]
            if len(ex.names or []) != rows.shape[1]:
                raise InputError(f"{self.where}: field {ex.field!r} of {self.topic} changes length "
                                 f"({len(ex.names or [])} → {rows.shape[1]})")
            self._blocks[k].append(rows)
            self._rows[k] = []
        try:  # a damaged container can hand back stamps that are not integers
            stamps = np.array(self._stamps, dtype=np.int64).reshape(n, 2)
            logs = np.array(self._logs, dtype=np.int64)
        except (ValueError, TypeError, OverflowError):
            raise InputError(f"{self.where}: {self.topic} has message stamps or log times that are not "
                             "integers (damaged file?)") from None
        self._tblocks.append(stamps[:, 0] * 1_000_000_000 + stamps[:, 1])
        self._lblocks.append(logs)
        self._stamps, self._logs = [], []

    def finish(self) -> list[Stream]:
        """One :class:`Stream` per extractor, in the order the messages were added."""
        self._flush()
        if not self._lblocks:
            raise InputError(f"{self.where}: topic {self.topic} has no messages")
        header = np.concatenate(self._tblocks)
        log = np.concatenate(self._lblocks)
        self._tblocks, self._lblocks = [], []
        use_header = self._header_seen and bool(header.any())
        out = []
        for k, ex in enumerate(self.extractors):
            from_header = use_header and ex.spec.stamp == "header"
            values = np.concatenate(self._blocks[k])
            self._blocks[k] = []  # free the blocks before the next stream is joined
            out.append(Stream(header if from_header else log, values,
                              list(ex.names or []), self.where,
                              {"topic": self.topic, "field": ex.field,
                               "stamp": "header" if from_header else "log"}))
        return out


def _identity(x: Any) -> Any:
    return x


def _stamp_getter(msg: Any) -> Callable[[Any], tuple[int, int]] | None:
    """A getter of (sec, nanosec) of ``header.stamp`` for messages shaped like ``msg``."""
    if not _has(msg, "header") or not _has(header := _get(msg, "header"), "stamp"):
        return None  # no std_msgs/Header stamp (e.g. a custom header): log time is used
    stamp = _get(header, "stamp")
    for s_key, n_key in (("sec", "nanosec"), ("secs", "nsecs"), ("sec", "nsec")):
        if _has(stamp, s_key) and _has(stamp, n_key):
            if isinstance(msg, dict):
                return lambda m, a=s_key, b=n_key: (m["header"]["stamp"][a], m["header"]["stamp"][b])
            return attrgetter(f"header.stamp.{s_key}", f"header.stamp.{n_key}")
    return None


def read_topics(specs: list[StreamOptions], msgtypes: dict[str, str], where: str
                ) -> tuple[dict[str, TopicCollector], list[tuple[str, int]]]:
    """Collectors per topic for ``specs`` and, per spec, where its stream will be."""
    by_topic: dict[str, list[FieldExtractor]] = {}
    slots = []
    for spec in specs:
        extractors = by_topic.setdefault(spec.topic, [])
        extractors.append(FieldExtractor(spec, msgtypes[spec.topic], where))
        slots.append((spec.topic, len(extractors) - 1))
    return {t: TopicCollector(ex, where) for t, ex in by_topic.items()}, slots


def finish_topics(collectors: dict[str, TopicCollector], slots: list[tuple[str, int]],
                  done: dict[str, list[Stream]] | None = None) -> list[Stream]:
    """The streams in the order of ``slots``: the collectors' and those already ``done``
    (topics read without decoding messages, :mod:`ccl_cli.io.layouts`)."""
    done = {**(done or {}), **{t: c.finish() for t, c in collectors.items()}}
    return [done[t][k] for t, k in slots]


# -- ccl inspect ------------------------------------------------------------------------------
def message_fields(msg: Any) -> list[str]:
    """The public field names of a decoded message."""
    return [k for k in _fields_of(msg, declared=True) if not k.startswith("_")]


def joint_names(msg: Any) -> list[str] | None:
    """``name`` of a JointState message, when it is a non-empty list of strings."""
    names = msg.get("name") if isinstance(msg, dict) else getattr(msg, "name", None)
    if isinstance(names, list | tuple) and names and all(isinstance(n, str) for n in names):
        return list(names)
    return None


class TopicReader(StreamReader):
    """A file of topics (bags, MCAP): :meth:`first_messages` gives, per topic, the log
    time of every message and the first message decoded; :meth:`inspect` lists them."""

    def first_messages(self) -> dict[str, tuple[np.ndarray, Any]]:
        raise NotImplementedError

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        """Per topic: type, count, the rate over the active time (pauses longer than ``gap``
        left out), fields and joint names; and the demonstrations of the state topic (the
        configured one, else the busiest) split on pauses longer than ``gap``."""
        info = self.listing()
        out = self.span(info)
        span = out["duration_s"]
        listing = info["topics"]
        for topic in listing.values():
            topic["rate_hz"] = (topic["count"] - 1) / span if span > 0 and topic["count"] > 1 else None
        out["topics"] = listing
        topics = self.first_messages()
        for name, (t_ns, msg) in topics.items():
            entry = listing.setdefault(name, {"type": "", "count": int(t_ns.size)})
            act = activity(t_ns, gap)
            entry.update({"rate_hz": act["rate_hz"], "active_s": act["active_s"],
                          "fields": message_fields(msg)})
            joints = joint_names(msg) if "JointState" in str(entry.get("type")) else None
            if joints:
                entry["joint_names"] = joints
        state = self.options.state.topic if self.options.state is not None else None
        if state not in topics:
            state = max(topics, key=lambda k: topics[k][0].size) if topics else None
        if state is not None:
            act = activity(topics[state][0], gap)
            out.update({"demos": act["demos"], "demos_from": state, "gap_s": act["gap_s"]})
            if "gap_rule" in act:
                out["gap_rule"] = act["gap_rule"]
        return out
