"""The index of a ROS 1 bag (format 2.0) read with NumPy: connections, chunks and, per
connection, the log time and place of every message, without an object per message.

A bag's index sits at its end: connection records, then one chunk-info record per chunk;
after each chunk record come its index-data records, (sec, nsec, offset) × count per
connection. Chunks are decompressed with rosbags' own codecs. Every size a record
declares is checked (:func:`~ccl_cli.io.limits.check_claim`) before it is read. The
message-by-message path (rosbags' reader, :mod:`ccl_cli.io.formats.bag`) is the fallback
for anything this does not read.
"""

from __future__ import annotations

import bisect
import io
import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.limits import check_claim, check_span, open_regular

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG, OP_BAG_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7
#: reads up to this size are not checked against the size cap first
SMALL_READ = 1 << 16
#: bytes read at a chunk's position for its record header (names, compression, sizes)
HEAD_READ = 4096


@dataclass
class Connection:
    """One connection: its id, topic, ROS 1 type name and message definition text."""

    id: int
    topic: str
    msgtype: str
    msgdef: str


@dataclass
class Chunk:
    """Where a chunk's (compressed) data lies and how it is compressed."""

    data_pos: int
    data_len: int
    compression: str
    size: int


@dataclass
class BagIndex:
    """The connections and chunks of a bag, and per connection id an (n, 3) int64 array:
    log time (ns), chunk number, byte offset of the record in the decompressed chunk."""

    connections: list[Connection]
    chunks: list[Chunk]
    entries: dict[int, np.ndarray] = field(default_factory=dict)


class _Records:
    """Bounded reads of the bag's records from ``f`` (the bag, or a block of it in memory)
    of ``size`` bytes."""

    def __init__(self, f: IO[bytes], where: str, size: int) -> None:
        self.f, self.where, self.size = f, where, size

    def exact(self, n: int, what: str) -> bytes:
        if n > SMALL_READ:
            check_claim(self.where, what, n, 1, self.size)
        raw = self.f.read(n)
        if len(raw) != n:
            raise InputError(f"{self.where}: {what} is truncated (damaged bag?)")
        return raw

    def u32(self, what: str) -> int:
        return struct.unpack("<I", self.exact(4, what))[0]

    def header(self, what: str) -> dict[str, bytes]:
        """The fields of a record header (``name=value``)."""
        raw = self.exact(self.u32(what), what)
        fields, at = {}, 0
        while at < len(raw):
            (n,) = struct.unpack_from("<I", raw, at) if at + 4 <= len(raw) else (len(raw),)
            item = raw[at + 4:at + 4 + n]
            if at + 4 + n > len(raw) or b"=" not in item:
                raise InputError(f"{self.where}: {what} has a malformed header field (damaged bag?)")
            name, value = item.split(b"=", 1)
            fields[name.decode("latin-1")] = value
            at += 4 + n
        return fields

    def record(self, op: int, what: str) -> tuple[dict[str, bytes], int]:
        """A record's header (checked to be of type ``op``) and its data length; the file is
        left at the start of the data."""
        fields = self.header(what)
        if fields.get("op") != bytes([op]):
            raise InputError(f"{self.where}: expected {what} (op {op}), found op {fields.get('op')!r}")
        return fields, self.u32(what)


def _int(fields: dict[str, bytes], key: str, fmt: str, where: str) -> int:
    try:
        return struct.unpack(fmt, fields[key])[0]
    except (KeyError, struct.error):
        raise InputError(f"{where}: a bag record lacks a valid {key!r} field (damaged bag?)") from None


def _data_fields(raw: bytes) -> dict[str, str]:
    """A connection record's data: header-style fields (type, md5sum, message_definition)."""
    out, at = {}, 0
    while at + 4 <= len(raw):
        (n,) = struct.unpack_from("<I", raw, at)
        name, _, value = raw[at + 4:at + 4 + n].partition(b"=")
        out[name.decode("latin-1")] = value.decode("utf-8", "replace")
        at += 4 + n
    return out


def _block(f: IO[bytes], start: int, stop: int, what: str, where: str, size: int) -> _Records:
    """The bytes [start, stop) of the bag, read at once, as records read from memory; the
    span is checked against the file's ``size`` first (:func:`~ccl_cli.io.limits.check_span`)."""
    check_span(where, what, start, stop, size)
    check_claim(where, what, stop - start, 1, size)
    f.seek(start)
    raw = f.read(stop - start)
    return _Records(io.BytesIO(raw), where, len(raw))


def in_order(keys: np.ndarray) -> bool:
    """Whether the rows of the (n, k) integer ``keys`` are in lexicographic order (equal rows
    allowed): a pass over the first column, the next ones only while some rows tie."""
    undecided = None  # rows equal to their successor in every column so far
    for col in keys.T:
        back = col[1:] < col[:-1]  # compared in place: no (n - 1,) int64 differences
        if bool((back if undecided is None else undecided & back).any()):
            return False
        same = col[1:] == col[:-1]
        undecided = same if undecided is None else undecided & same
        if not undecided.any():
            return True
    return True


def read_index(path: Path) -> BagIndex:
    """The index of the ROS 1 bag at ``path``; InputError for what is not a readable bag 2.0.

    The index section (connection and chunk-info records) is read in one piece; per chunk,
    its record header and the index data records after its data are read in one piece
    each, their (sec, nsec, offset) entries copied into arrays allocated once from the
    chunk-info counts."""
    where = str(path)
    with open_regular(path, "the bag") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise InputError(f"{where}: not a ROS 1 bag of format 2.0")
        size = os.fstat(f.fileno()).st_size
        rec = _Records(f, where, size)
        head, _ = rec.record(OP_BAG_HEADER, "the bag header")
        index_pos = _int(head, "index_pos", "<Q", where)
        n_conn = _int(head, "conn_count", "<I", where)
        n_chunks = _int(head, "chunk_count", "<I", where)
        if index_pos == 0:
            raise InputError(f"{where}: the bag is not indexed (reindex it with rosbag reindex)")
        check_span(where, "the bag's index", index_pos, index_pos, size - 1)
        rec = _block(f, index_pos, size, "the bag's index", where, size)
        connections = []
        for _ in range(n_conn):
            fields, n = rec.record(OP_CONNECTION, "a connection record")
            data = _data_fields(rec.exact(n, "a connection record"))
            connections.append(Connection(_int(fields, "conn", "<I", where),
                                          fields.get("topic", b"").decode("utf-8", "replace"),
                                          data.get("type", ""), data.get("message_definition", "")))
        infos = []  # per chunk: its position and {connection: message count}
        for _ in range(n_chunks):
            fields, n = rec.record(OP_CHUNK_INFO, "a chunk info record")
            counts = np.frombuffer(rec.exact(n, "a chunk info record"), dtype="<u4")
            if counts.size != 2 * _int(fields, "count", "<I", where):
                raise InputError(f"{where}: a chunk info record is truncated (damaged bag?)")
            infos.append((_int(fields, "chunk_pos", "<Q", where), dict(counts.reshape(-1, 2).tolist())))
        totals: dict[int, int] = {c.id: 0 for c in connections}
        for _, counts in infos:
            for conn, count in counts.items():
                if conn not in totals:
                    raise InputError(f"{where}: a chunk holds connection {conn}, not in the index")
                totals[conn] += count
        check_claim(where, "the index entries", sum(totals.values()) * 24, 1, size)
        # per connection, column-major: log time (ns), chunk number, offset in the chunk
        columns = {conn: np.empty((3, n), dtype=np.int64) for conn, n in totals.items()}
        filled = dict.fromkeys(totals, 0)
        ends = sorted({pos for pos, _ in infos} | {index_pos})
        chunks: list[Chunk] = []
        for number, (pos, counts) in enumerate(infos):
            check_span(where, f"chunk {number}", pos, pos, index_pos,
                       f"the {index_pos} bytes before the bag's index")  # where chunks lie
            top = _block(f, pos, min(pos + HEAD_READ, size), f"chunk {number}", where, size)
            fields, n = top.record(OP_CHUNK, "a chunk")
            data_pos = pos + top.f.tell()
            check_span(where, f"the data of chunk {number}", data_pos, data_pos + n, size)
            chunks.append(Chunk(data_pos, n, fields.get("compression", b"").decode("latin-1"),
                                _int(fields, "size", "<I", where)))
            stop = ends[bisect.bisect_right(ends, pos)] if pos < index_pos else size
            block = _block(f, data_pos + n, stop, "the index data of a chunk", where, size)
            for _ in counts:
                fields, n = block.record(OP_INDEX, "an index data record")
                conn, count = _int(fields, "conn", "<I", where), _int(fields, "count", "<I", where)
                at = filled.get(conn, -1)
                if n != 12 * count or count != counts.get(conn) or at < 0:
                    raise InputError(f"{where}: an index data record disagrees with its chunk info "
                                     "(damaged bag?)")
                raw = np.frombuffer(block.exact(n, "an index data record"), dtype="<u4").reshape(-1, 3)
                out = columns[conn][:, at:at + count]
                np.multiply(raw[:, 0], 1_000_000_000, out=out[0], dtype=np.int64)  # sec, nsec
                out[0] += raw[:, 1]
                out[1] = number
                out[2] = raw[:, 2]
                filled[conn] = at + count
        index = BagIndex(connections, chunks)
        for conn, both in columns.items():
            entries = both.T  # in file order; rosbags reads in log time, then chunk, then place
            if not in_order(entries):
                entries = entries[np.lexsort((entries[:, 2], entries[:, 1], entries[:, 0]))]
            index.entries[conn] = entries
        return index


def read_chunk(f: IO[bytes], chunk: Chunk, where: str) -> np.ndarray:
    """The decompressed bytes of ``chunk`` (rosbags' codecs) as uint8."""
    from rosbags.rosbag1.reader import decompressors

    from ccl_cli.io.library_errors import library_call

    decompress = decompressors.get(chunk.compression)
    if decompress is None:
        raise InputError(f"{where}: chunk compression {chunk.compression!r} is not supported")
    size = os.fstat(f.fileno()).st_size
    check_span(where, f"the chunk at byte {chunk.data_pos}", chunk.data_pos, chunk.data_pos + chunk.data_len,
               size)
    check_claim(where, f"the chunk at byte {chunk.data_pos}", max(chunk.size, chunk.data_len), 1, size)
    f.seek(chunk.data_pos)
    raw = f.read(chunk.data_len)
    if len(raw) != chunk.data_len:
        raise InputError(f"{where}: the chunk at byte {chunk.data_pos} is truncated")
    data = library_call(where, f"decompress the chunk at byte {chunk.data_pos}", decompress, raw)
    return np.frombuffer(data, dtype=np.uint8)
