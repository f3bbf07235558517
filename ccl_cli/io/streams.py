"""What readers return: time-stamped numeric streams, and how to pick them from messages.

A :class:`Stream` is one selection from one file (a topic's field, or CSV columns):
``t_ns`` (n,) int64 nanoseconds and ``values`` (n, d) float64, with a name per column.
:class:`StreamSpec` says what to pick. :class:`FieldExtractor` turns decoded messages
(rosbags dataclasses, mcap ROS 1/ROS 2 objects or JSON dicts alike) into numbers.
"""

from __future__ import annotations

import contextlib
import functools
import importlib
from collections.abc import Callable, Iterable, Iterator
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
        if not self._compiled or (self._name_of is not None and self._name_of(msg) != self._names):
            self._checked(msg)
        for rows, get in zip(self._rows, self._getters, strict=True):
            rows.append(get(msg))
        self._stamps.append(self._stamp(msg) if self._stamp is not None else (0, 0))
        self._logs.append(log_ns)
        if len(self._logs) >= self.BLOCK:
            self._flush()

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
            if ex.spec.joints is not None and ex.kind == "JointState":
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
            except ValueError:
                raise InputError(f"{self.where}: field {ex.field!r} of {self.topic} changes length "
                                 "between messages") from None
            rows = rows.reshape(n, -1)
            if ex.spec.joints is not None and ex.kind == "JointState" and self._names is not None:
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


def read_topics(specs: list[StreamSpec], msgtypes: dict[str, str], where: str
                ) -> tuple[dict[str, TopicCollector], list[tuple[str, int]]]:
    """Collectors per topic for ``specs`` and, per spec, where its stream will be."""
    by_topic: dict[str, list[FieldExtractor]] = {}
    slots = []
    for spec in specs:
        extractors = by_topic.setdefault(spec.topic, [])
        extractors.append(FieldExtractor(spec, msgtypes[spec.topic], where))
        slots.append((spec.topic, len(extractors) - 1))
    return {t: TopicCollector(ex, where) for t, ex in by_topic.items()}, slots


@functools.cache
def library_errors() -> tuple[type[BaseException], ...]:
    """Exception types the bag and MCAP libraries raise on corrupt or truncated input:
    their own classes, and the built-in ones their parsers let through (struct, index,
    decoding, compression errors). Only ever caught around a library call."""
    import struct

    found: list[type[BaseException]] = [struct.error, ValueError, IndexError, KeyError, TypeError,
                                        AttributeError, UnicodeDecodeError, EOFError, OverflowError,
                                        RuntimeError, OSError, AssertionError, NotImplementedError,
                                        RecursionError, MemoryError, LookupError,
                                        SyntaxError, NameError]  # mcap-ros1/2 build message classes
    for module, names in (("rosbags.rosbag1", ["ReaderError"]), ("rosbags.rosbag2", ["ReaderError"]),
                          ("rosbags.serde", ["SerdeError"]), ("rosbags.typesys", ["TypesysError"]),
                          ("rosbags.highlevel", ["AnyReaderError"]), ("mcap.exceptions", ["McapError"]),
                          ("mcap_ros1._vendor.genpy.message", ["MessageException"]),
                          ("mcap_ros1._vendor.genmsg.base", ["InvalidMsgSpec", "MsgGenerationException"]),
                          ("mcap_ros2._vendor.rosidl_adapter.parser", ["InvalidSpecification",
                                                                       "InvalidValue"])):
        try:
            mod = importlib.import_module(module)
        except ImportError:
            continue
        found += [getattr(mod, n) for n in names if isinstance(getattr(mod, n, None), type)]
    return tuple(found)


#: packages whose own exception classes the readers meet (the libraries, and what they use:
#: compression and sqlite)
LIBRARY_PACKAGES = {"rosbags", "mcap", "mcap_ros1", "mcap_ros2", "zstandard", "backports", "lz4", "apsw",
                    "sqlite3", "_sqlite3", "ruamel", "yaml", "bz2", "_bz2", "zlib", "lzma", "_lzma"}


def _is_library_error(exc: BaseException) -> bool:
    return isinstance(exc, library_errors()) or \
        type(exc).__module__.split(".")[0] in LIBRARY_PACKAGES


def library_call(where: str, what: str, fn: Callable[..., Any], *args: Any, **kwargs: Any) -> Any:
    """``fn(*args, **kwargs)`` — a call into a reader library — with the library's
    failures (its own exception classes, or built-in ones its parsers let through)
    turned into one :class:`InputError` line (``where: cannot what (...)``). Anything
    else propagates."""
    try:
        return fn(*args, **kwargs)
    except Exception as exc:  # filtered: only the libraries' exception types are converted
        if not _is_library_error(exc):
            raise
        raise InputError(f"{where}: cannot {what} ({type(exc).__name__}: {_first_line(exc)})") from None


def library_iter(where: str, what: str, iterable: Iterable[Any]) -> Iterator[Any]:
    """Items of a library's iterator; its failures (only those raised while the
    library produces the next item, never in the caller's loop body) become InputError."""
    it = library_call(where, what, iter, iterable)
    while True:
        try:
            item = next(it)
        except StopIteration:
            return
        except Exception as exc:  # filtered: only the libraries' exception types are converted
            if not _is_library_error(exc):
                raise
            raise InputError(f"{where}: cannot {what} ({type(exc).__name__}: {_first_line(exc)})") from None
        yield item


@contextlib.contextmanager
def decoding(where: str, topics) -> Iterator[None]:
    """Exceptions of the reader libraries' own classes (not built-in ones, which our code
    raises too) raised inside the block → one InputError line. Prefer
    :func:`library_call` / :func:`library_iter`, which also cover built-in types."""
    try:
        yield
    except Exception as exc:  # filtered to the libraries' own classes below
        if type(exc).__module__.split(".")[0] not in LIBRARY_PACKAGES:
            raise
        raise InputError(f"{where}: cannot decode {', '.join(topics)} ({type(exc).__name__}: "
                         f"{_first_line(exc)})") from None


def _first_line(exc: BaseException) -> str:
    return (str(exc).splitlines() or [""])[0][:200]


def finish_topics(collectors: dict[str, TopicCollector], slots: list[tuple[str, int]]) -> list[Stream]:
    done = {t: c.finish() for t, c in collectors.items()}
    return [done[t][k] for t, k in slots]
