"""Fixed-layout messages read with NumPy, without a Python object per message.

A topic whose messages all serialise to the same bytes except their numbers (a
JointState with the same joint names and counts in every message, a PoseStamped with
the same ``frame_id``, …) is a table of fixed-size records: :func:`layout_of` walks the
first message once and finds where each float64 field and the header stamp lie;
:class:`FixedTopic` then reads the records of a chunk as one (n, record size) byte table
(a view of the chunk when they lie back to back, else one fancy index), checks that every
byte outside the numbers and stamps equals the first record's (compared as 8-byte words)
and copies the number columns straight into arrays allocated once from the index's
count. A message that differs (names changing, differing joint counts, another
``frame_id`` length) raises :class:`NotFixed` and the caller falls back to the
libraries' decoders. Serialisations: ROS 1 (``ros1``) and little-endian CDR (``cdr``).

Supported types (the part after the package): JointState, PoseStamped, TwistStamped,
WrenchStamped, PointStamped, Vector3Stamped, Float64MultiArray.
"""

from __future__ import annotations

import struct
from collections.abc import Callable
from dataclasses import dataclass

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.streams import Stream


class NotFixed(Exception):
    """The topic's messages are not all laid out alike: read it with the library decoders."""


@dataclass
class Layout:
    """Where the numbers of one serialised message lie.

    ``size``: bytes per message; ``runs``: (field path, byte offset, float64 count) in
    serialisation order; ``stamp``: byte offsets of ``header.stamp`` (sec, nanosec) or
    None; ``varying``: (size,) bool, the bytes that may differ between messages."""

    size: int
    runs: list[tuple[str, int, int]]
    stamp: tuple[int, int] | None
    varying: np.ndarray

    def columns(self, field: str) -> list[tuple[int, int]]:
        """(offset, count) runs of ``field`` and everything under it, in order."""
        found = [(o, k) for path, o, k in self.runs if path == field or path.startswith(field + ".")]
        if not found:
            raise NotFixed(field)
        return found


class _Walk:
    """A cursor over one serialised message that records where the numbers are."""

    def __init__(self, raw: bytes, cdr: bool) -> None:
        if cdr and raw[:2] != b"\x00\x01":  # CDR little endian only
            raise NotFixed("CDR encapsulation is not little endian")
        self.raw, self.cdr = raw, cdr
        self.origin = self.pos = 4 if cdr else 0
        self.runs: list[tuple[str, int, int]] = []
        self.varying = np.zeros(len(raw), dtype=bool)
        self.stamp: tuple[int, int] | None = None

    def _take(self, n: int) -> int:
        at = self.pos
        if n < 0 or at + n > len(self.raw):
            raise NotFixed("message shorter than its layout")
        self.pos += n
        return at

    def align(self, n: int) -> None:
        if self.cdr:
            self.pos += -(self.pos - self.origin) % n

    def u32(self, varying: bool = False) -> int:
        self.align(4)
        at = self._take(4)
        self.varying[at:at + 4] |= varying
        return struct.unpack_from("<I", self.raw, at)[0]

    def string(self) -> None:
        self._take(self.u32())  # CDR counts the terminating NUL, ROS 1 does not: same walk

    def strings(self) -> None:
        for _ in range(self.u32()):
            self.string()

    def floats(self, path: str, count: int) -> None:
        if count:  # CDR aligns each element: an empty sequence is not padded
            self.align(8)
        at = self._take(8 * count)
        self.varying[at:at + 8 * count] = True
        self.runs.append((path, at, count))

    def float_seq(self, path: str) -> None:
        self.floats(path, self.u32())

    def vector(self, path: str, keys: str = "xyz") -> None:
        for key in keys:
            self.floats(f"{path}.{key}", 1)

    def header(self) -> None:
        if not self.cdr:
            self.u32(varying=True)  # seq
        sec = self.pos
        self.u32(varying=True)
        self.u32(varying=True)
        self.stamp = (sec, sec + 4)
        self.string()  # frame_id


def _joint_state(w: _Walk) -> None:
    w.header()
    w.strings()
    for name in ("position", "velocity", "effort"):
        w.float_seq(name)


def _stamped(*parts: tuple[str, str]) -> Callable[[_Walk], None]:
    def walk(w: _Walk) -> None:
        w.header()
        for path, keys in parts:
            w.vector(path, keys)
    return walk


def _multi_array(w: _Walk) -> None:
    for _ in range(w.u32()):  # layout.dim: label, size, stride
        w.string()
        w.u32()
        w.u32()
    w.u32()  # layout.data_offset
    w.float_seq("data")


#: how each supported type serialises (ROS 1 and CDR share the field order)
WALKS: dict[str, Callable[[_Walk], None]] = {
    "JointState": _joint_state,
    "PoseStamped": _stamped(("pose.position", "xyz"), ("pose.orientation", "xyzw")),
    "TwistStamped": _stamped(("twist.linear", "xyz"), ("twist.angular", "xyz")),
    "WrenchStamped": _stamped(("wrench.force", "xyz"), ("wrench.torque", "xyz")),
    "PointStamped": _stamped(("point", "xyz")),
    "Vector3Stamped": _stamped(("vector", "xyz")),
    "Float64MultiArray": _multi_array,
}


def layout_of(kind: str, raw: bytes, cdr: bool) -> Layout:
    """The layout of message ``raw`` of type ``kind`` (short name); :class:`NotFixed` when
    the type is not supported or the bytes do not walk."""
    walk = WALKS.get(kind)
    if walk is None:
        raise NotFixed(kind)
    w = _Walk(raw, cdr)
    try:
        walk(w)
    except struct.error:
        raise NotFixed("message shorter than its layout") from None
    if w.pos != len(raw):
        raise NotFixed("trailing bytes after the layout")
    return Layout(len(raw), w.runs, w.stamp, w.varying)


def gather_rows(buf: np.ndarray, starts: np.ndarray, size: int) -> np.ndarray:
    """(n, size) uint8: the ``size`` bytes at each of ``starts`` in ``buf`` (one fancy index)."""
    if starts.size and (starts.min() < 0 or starts.max() + size > buf.size):
        raise NotFixed("a record runs past its chunk")
    return np.lib.stride_tricks.sliding_window_view(buf, size)[starts]  # copies n × size bytes only


def read_uint(buf: np.ndarray, at: np.ndarray, width: int) -> np.ndarray:
    """Little-endian unsigned integers of ``width`` bytes (2, 4, 8) at byte offsets ``at``."""
    return gather_rows(buf, at, width).view(f"<u{width}")[:, 0]


def record_rows(buf: np.ndarray, starts: np.ndarray, size: int) -> np.ndarray:
    """(n, size) uint8 rows of the records at ``starts`` (increasing) in ``buf``: a view of
    ``buf`` when the records lie back to back (one topic per chunk), else a gathered copy."""
    n = starts.size
    first = int(starts[0]) if n else 0
    if n and first >= 0 and first + n * size <= buf.size and \
            (n == 1 or bool((np.diff(starts) == size).all())):
        return buf[first:first + n * size].reshape(n, size)
    return gather_rows(buf, starts, size)


def _words(a: int, b: int) -> list[tuple[int, int]]:
    """The bytes [a, b) as little-endian words (offset, width), widest first: 8-byte words
    from ``a`` and, for a remainder, one word ending at ``b`` (overlapping the one before
    it, never leaving [a, b))."""
    width = next(w for w in (8, 4, 2, 1) if w <= b - a)
    out = [(o, width) for o in range(a, b - width + 1, width)]
    if (b - a) % width:
        out.append((b - width, width))
    return out


def _float_runs(offsets: np.ndarray) -> list[tuple[int, int, int]]:
    """Byte offsets of float64 columns grouped into (byte offset, count, first column) runs
    of adjacent numbers, each copied with one strided view."""
    if not offsets.size:
        return []
    breaks = np.flatnonzero(np.diff(offsets) != 8) + 1
    edges = np.r_[0, breaks, offsets.size]
    return [(int(offsets[lo]), int(hi - lo), int(lo)) for lo, hi in zip(edges[:-1], edges[1:], strict=True)]


@dataclass
class Selection:
    """One stream of a fixed topic: byte offsets (in the message) of its float64 columns in
    output order, the column names and whether it is stamped by ``header.stamp``."""

    offsets: np.ndarray
    names: list[str]
    header: bool
    field: str


class FixedTopic:
    """The streams of one topic gathered chunk by chunk into arrays allocated once.

    A record is ``head`` (the container's bytes before the message: record header, log
    time, …; ``head_varying`` marks those that may differ) followed by the message. Every
    record must equal the first (``head`` + ``first``) outside the numbers, stamps and
    varying head bytes. ``total``: the number of messages (from the index)."""

    def __init__(self, topic: str, where: str, layout: Layout, first: bytes, selections: list[Selection],
                 total: int, head: bytes = b"", head_varying: np.ndarray | None = None) -> None:
        self.topic, self.where, self.layout = topic, where, layout
        self.record = np.frombuffer(head + first, dtype=np.uint8)
        self.size = self.record.size
        skip = len(head)
        varying = np.r_[np.zeros(skip, bool) if head_varying is None else head_varying, layout.varying]
        edges = np.flatnonzero(np.diff(np.r_[0, (~varying).astype(np.int8), 0]))
        #: the fixed bytes as words (offset, width, the first record's word there): compared
        #: one column at a time, n elements a call (a row at a time costs a call per record)
        self.checks = [(o, w, int.from_bytes(self.record[o:o + w].tobytes(), "little"))
                       for a, b in zip(edges[::2].tolist(), edges[1::2].tolist(), strict=True)
                       for o, w in _words(a, b)]
        self.selections = selections
        self.copies = [_float_runs(skip + s.offsets) for s in selections]
        self.values = [np.empty((total, s.offsets.size)) for s in selections]
        self.stamp = None if layout.stamp is None else skip + layout.stamp[0]
        self.stamps = np.zeros(total, dtype=np.int64) if layout.stamp is not None else None
        self.logs = np.empty(total, dtype=np.int64)
        self.n = 0

    def add(self, buf: np.ndarray, starts: np.ndarray, log_ns: np.ndarray) -> None:
        """Records of one chunk: ``buf`` (uint8), where each record starts (increasing) and
        their log times (ns). :class:`NotFixed` when one is laid out unlike the first."""
        n = starts.size
        if n == 0:
            return
        if self.n + n > self.logs.size:
            raise NotFixed("more messages than the index counts")
        rows = record_rows(buf, starts, self.size)
        for o, w, first in self.checks:
            if not (rows[:, o:o + w].view(f"<u{w}")[:, 0] == first).all():
                raise NotFixed("a record's non-numeric bytes differ from the first's")
        span = slice(self.n, self.n + n)
        for copies, out in zip(self.copies, self.values, strict=True):
            for o, k, col in copies:
                out[span, col:col + k] = rows[:, o:o + 8 * k].view("<f8")
        if self.stamps is not None:
            sec_nsec = rows[:, self.stamp:self.stamp + 8].view("<u4")
            np.multiply(sec_nsec[:, 0], 1_000_000_000, out=self.stamps[span], dtype=np.int64)
            self.stamps[span] += sec_nsec[:, 1]
        self.logs[span] = log_ns
        self.n += n

    def finish(self) -> list[Stream]:
        """One :class:`Stream` per selection, in log-time order (ties: file order), as the
        message-by-message path builds them."""
        n = self.n
        if n == 0:
            raise InputError(f"{self.where}: topic {self.topic} has no messages")
        logs = self.logs[:n]
        order = None if bool((logs[1:] >= logs[:-1]).all()) else np.argsort(logs, kind="stable")
        header = self.stamps[:n] if self.stamps is not None else None
        use_header = header is not None and bool(header.any())
        out = []
        for sel, values in zip(self.selections, self.values, strict=True):
            values = values[:n]
            if order is not None:
                values = values[order]
            stamp = header if use_header and sel.header else logs
            out.append(Stream(stamp if order is None else stamp[order], values, sel.names, self.where,
                              {"topic": self.topic, "field": sel.field,
                               "stamp": "header" if use_header and sel.header else "log"}))
        return out


def fixed_topic(topic: str, kind: str, cdr: bool, first_raw: bytes, first_msg: object,
                extractors: list, total: int, where: str, head: bytes = b"",
                head_varying: np.ndarray | None = None) -> FixedTopic:
    """A :class:`FixedTopic` for ``extractors`` (:class:`~ccl_cli.io.messages.FieldExtractor`
    of one topic), set up from its first message: ``first_raw`` (serialised) and
    ``first_msg`` (decoded by the library); ``head``/``head_varying``: the container's bytes
    before each message (:class:`FixedTopic`). The extractors check the decoded message as
    on the message-by-message path (precise errors for a wrong field or joint); the
    gathered numbers of the first message must equal the library's, else
    :class:`NotFixed`."""
    layout = layout_of(kind, first_raw, cdr)
    message = np.frombuffer(first_raw, dtype=np.uint8)
    selections = []
    for ex in extractors:
        expected = np.asarray(ex.values(first_msg), dtype=float).ravel()
        offsets = np.concatenate([o + 8 * np.arange(k) for o, k in layout.columns(ex.field)])
        if ex.spec.joints is not None and ex.kind == "JointState" and not ex._joint_identity:
            offsets = offsets[ex._joint_index]  # the wanted joints, in the wanted order
        got = message[offsets[:, None] + np.arange(8)].view("<f8")[:, 0]
        if got.shape != expected.shape or not np.array_equal(got, expected, equal_nan=True) \
                or got.size != len(ex.names or []):
            raise NotFixed(f"{ex.field}: the gathered numbers differ from the library's")
        selections.append(Selection(offsets, list(ex.names or []), ex.spec.stamp == "header", ex.field))
    return FixedTopic(topic, where, layout, first_raw, selections, total, head, head_varying)
