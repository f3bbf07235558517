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

import os
import struct
from dataclasses import dataclass, field
from pathlib import Path
from typing import IO

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.limits import check_claim, open_regular

MAGIC = b"#ROSBAG V2.0\n"
OP_MSG, OP_BAG_HEADER, OP_INDEX, OP_CHUNK, OP_CHUNK_INFO, OP_CONNECTION = 2, 3, 4, 5, 6, 7


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
    """Bounded reads of the bag's records."""

    def __init__(self, f: IO[bytes], where: str) -> None:
        self.f, self.where = f, where
        self.size = os.fstat(f.fileno()).st_size

    def exact(self, n: int, what: str) -> bytes:
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


def read_index(path: Path) -> BagIndex:
    """The index of the ROS 1 bag at ``path``; InputError for what is not a readable bag 2.0."""
    where = str(path)
    with open_regular(path, "the bag") as f:
        if f.read(len(MAGIC)) != MAGIC:
            raise InputError(f"{where}: not a ROS 1 bag of format 2.0")
        rec = _Records(f, where)
        head, _ = rec.record(OP_BAG_HEADER, "the bag header")
        index_pos = _int(head, "index_pos", "<Q", where)
        n_conn = _int(head, "conn_count", "<I", where)
        n_chunks = _int(head, "chunk_count", "<I", where)
        if index_pos == 0 or index_pos >= rec.size:
            raise InputError(f"{where}: the bag is not indexed (reindex it with rosbag reindex)")
        f.seek(index_pos)
        connections = []
        for _ in range(n_conn):
            fields, n = rec.record(OP_CONNECTION, "a connection record")
            data = _data_fields(rec.exact(n, "a connection record"))
            connections.append(Connection(_int(fields, "conn", "<I", where),
                                          fields.get("topic", b"").decode("utf-8", "replace"),
                                          data.get("type", ""), data.get("message_definition", "")))
        infos = []
        for _ in range(n_chunks):
            fields, n = rec.record(OP_CHUNK_INFO, "a chunk info record")
            rec.exact(n, "a chunk info record")
            infos.append((_int(fields, "chunk_pos", "<Q", where), _int(fields, "count", "<I", where)))
        chunks: list[Chunk] = []
        parts: dict[int, list[np.ndarray]] = {}
        for number, (pos, n_conns) in enumerate(infos):
            f.seek(pos)
            fields, n = rec.record(OP_CHUNK, "a chunk")
            chunks.append(Chunk(f.tell(), n, fields.get("compression", b"").decode("latin-1"),
                                _int(fields, "size", "<I", where)))
            f.seek(n, os.SEEK_CUR)
            for _ in range(n_conns):
                fields, n = rec.record(OP_INDEX, "an index data record")
                raw = np.frombuffer(rec.exact(n, "an index data record"), dtype="<u4")
                if raw.size % 3:
                    raise InputError(f"{where}: an index data record is truncated (damaged bag?)")
                raw = raw.reshape(-1, 3).astype(np.int64)
                entries = np.empty_like(raw)
                entries[:, 0] = raw[:, 0] * 1_000_000_000 + raw[:, 1]
                entries[:, 1] = number
                entries[:, 2] = raw[:, 2]
                parts.setdefault(_int(fields, "conn", "<I", where), []).append(entries)
        index = BagIndex(connections, chunks)
        index.entries = {c.id: np.zeros((0, 3), dtype=np.int64) for c in connections}
        for conn, blocks in parts.items():
            entries = np.concatenate(blocks)
            # the order rosbags reads in: log time, then chunk, then place in the chunk
            index.entries[conn] = entries[np.lexsort((entries[:, 2], entries[:, 1], entries[:, 0]))]
        return index


def read_chunk(f: IO[bytes], chunk: Chunk, where: str) -> np.ndarray:
    """The decompressed bytes of ``chunk`` (rosbags' codecs) as uint8."""
    from rosbags.rosbag1.reader import decompressors

    from ccl_cli.io.library_errors import library_call

    decompress = decompressors.get(chunk.compression)
    if decompress is None:
        raise InputError(f"{where}: chunk compression {chunk.compression!r} is not supported")
    check_claim(where, f"the chunk at byte {chunk.data_pos}", max(chunk.size, chunk.data_len), 1,
                os.fstat(f.fileno()).st_size)
    f.seek(chunk.data_pos)
    raw = f.read(chunk.data_len)
    if len(raw) != chunk.data_len:
        raise InputError(f"{where}: the chunk at byte {chunk.data_pos} is truncated")
    data = library_call(where, f"decompress the chunk at byte {chunk.data_pos}", decompress, raw)
    return np.frombuffer(data, dtype=np.uint8)
