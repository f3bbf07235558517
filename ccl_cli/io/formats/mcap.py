"""Standalone MCAP files via ``mcap`` and its decoder factories.

Encodings: ``cdr`` with ``ros2msg`` schemas (mcap-ros2-support), ``ros1`` with
``ros1msg`` schemas (mcap-ros1-support), and ``json`` (decoded with the standard
library's json, which is what the encoding is).
"""

from __future__ import annotations

import json
import os
from collections.abc import Sequence
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.layouts import FixedTopic, NotFixed, fixed_topic
from ccl_cli.io.library_errors import library_call, library_iter
from ccl_cli.io.limits import check_claim, check_span, open_regular
from ccl_cli.io.messages import TopicReader, finish_topics, read_topics, short_type, type_name
from ccl_cli.io.options import StreamOptions
from ccl_cli.io.sniff import MCAP_MAGIC
from ccl_cli.io.streams import Stream
from ccl_cli.progress import progress_of

#: MCAP record opcodes, and the bytes of a Message record before its data (opcode, length,
#: channel id, sequence, log time, publish time)
MESSAGE_OPCODE, MESSAGE_INDEX_OPCODE = 0x05, 0x07
MESSAGE_PREFIX = 1 + 8 + 2 + 4 + 8 + 8


def _decoders():
    from mcap_ros1.decoder import DecoderFactory as Ros1Decoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    return [Ros2Decoders(), Ros1Decoders()]


class McapReader(TopicReader):
    """One standalone MCAP file (refused at once if it does not start with the MCAP magic).
    Messages are read in log-time order (in file order, mcap holds the file's data in
    memory; docs/readers.md)."""

    format = "mcap"

    def _open(self):
        where = str(self.path)
        f = open_regular(self.path, "the MCAP file")
        if f.read(len(MCAP_MAGIC)) != MCAP_MAGIC:
            f.close()
            raise InputError(f"{where}: not an MCAP file (no MCAP magic at the start)")
        f.seek(0)
        return f

    def _summary(self, f):
        from mcap.reader import make_reader

        where = str(self.path)
        reader = library_call(where, "read MCAP", make_reader, f, decoder_factories=_decoders())
        summary = library_call(where, "read MCAP", reader.get_summary)
        if summary is None:
            raise InputError(f"{where}: MCAP has no summary (truncated?)")
        size = os.fstat(f.fileno()).st_size
        for index in summary.chunk_indexes:  # where each chunk lies, and what it decompresses to
            what = f"the chunk at byte {index.chunk_start_offset}"
            start = int(index.chunk_start_offset)
            check_span(where, what, start, start + int(index.chunk_length), size)
            check_claim(where, what, max(int(index.uncompressed_size), int(index.chunk_length)), 1)
            for cid, offset in index.message_index_offsets.items():
                check_span(where, f"the message index of channel {cid}", int(offset), int(offset), size)
        return reader, summary

    def listing(self) -> dict[str, Any]:
        with self._open() as f:
            _, summary = self._summary(f)
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        topics = {}
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            topics[str(ch.topic)] = {"type": type_name(schema.name) if schema else "",
                                     "encoding": ch.message_encoding,
                                     "count": int(counts.get(cid, 0))}
        st = summary.statistics
        codecs = sorted({str(c.compression) or "none" for c in summary.chunk_indexes}) or ["none"]
        encodings = sorted({str(ch.message_encoding) for ch in summary.channels.values()})
        return {"start_ns": int(st.message_start_time) if st else 0,
                "end_ns": int(st.message_end_time) if st else 0,
                "storage": f"MCAP, {len(summary.chunk_indexes)} chunk(s)", "compression": ", ".join(codecs),
                "encoding": ", ".join(encodings), "topics": dict(sorted(topics.items()))}

    def streams(self, selections: Sequence[StreamOptions]) -> list[Stream]:
        """Several streams in one pass over the file (each message decoded once), in log-time
        order."""
        where = str(self.path)
        with self._open() as f:
            reader, summary = self._summary(f)
            msgtypes, encodings = {}, {}
            for selection in selections:
                channels = [c for c in summary.channels.values() if c.topic == selection.topic]
                if not channels:
                    have = ", ".join(sorted({str(c.topic) for c in summary.channels.values()})) or "none"
                    raise InputError(f"{where}: topic {selection.topic!r} not found (topics: {have})")
                schema = summary.schemas.get(channels[0].schema_id)
                msgtypes[selection.topic] = type_name(schema.name) if schema else ""
                encodings[selection.topic] = channels[0].message_encoding
            collectors, slots = read_topics(selections, msgtypes, where)
            done: dict[str, list[Stream]] = {}
            for topic, collector in collectors.items():
                fast = self._fixed(f, summary, topic, collector.extractors)
                if fast is not None:
                    done[topic] = fast
            collectors = {t: c for t, c in collectors.items() if t not in done}
            topics = list(collectors)
            if not topics:
                return finish_topics({}, slots, done)
            what = f"decode {', '.join(topics)}"
            if all(encodings[t] == "json" for t in topics):
                for _, channel, message in library_iter(where, what, reader.iter_messages(topics=topics)):
                    decoded = library_call(where, what, json.loads, message.data)
                    collectors[channel.topic].add(decoded, message.log_time)
            else:
                for _, channel, message, decoded in library_iter(where, what,
                                                                 reader.iter_decoded_messages(topics=topics)):
                    collectors[channel.topic].add(decoded, message.log_time)
            return finish_topics(collectors, slots, done)

    def _fixed(self, f, summary, topic: str, extractors: list) -> list[Stream] | None:
        """The streams of ``topic`` gathered with NumPy from the chunks (:mod:`ccl_cli.io.layouts`),
        or None when its messages are not all laid out alike (or not indexed): the caller
        decodes them message by message."""
        channels = [c for c in summary.channels.values() if c.topic == topic]
        if len(channels) != 1 or channels[0].message_encoding not in ("cdr", "ros1"):
            return None
        cid = channels[0].id
        chunks = sorted((c for c in summary.chunk_indexes if cid in c.message_index_offsets),
                        key=lambda c: c.chunk_start_offset)
        if not chunks or any(not c.message_index_offsets for c in summary.chunk_indexes):
            return None  # chunks without message indexes: which hold the topic is unknown
        indexes = [self._message_index(f, c.message_index_offsets[cid], cid) for c in chunks]
        total = sum(len(i) for i in indexes)
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        if total == 0 or total != int(counts.get(cid, total)):
            return None  # an index that does not count every message: decoded one by one
        gathered = None
        try:
            with progress_of(f"reading {topic}", sum(c.uncompressed_size for c in chunks)) as advance:
                for chunk_index, entries in zip(chunks, indexes, strict=True):
                    buf = self._chunk(f, chunk_index)
                    starts = entries[:, 1].astype(np.int64)
                    if not len(starts):
                        continue
                    if not bool((np.diff(starts) > 0).all()):
                        order = np.argsort(starts, kind="stable")
                        starts, entries = starts[order], entries[order]
                    if gathered is None:
                        gathered = self._first_fixed(summary, channels[0], buf, int(starts[0]), extractors,
                                                     total)
                    gathered.add(buf, starts, entries[:, 0].astype(np.int64))
                    advance(chunk_index.uncompressed_size)
        except NotFixed:
            return None
        return gathered.finish()

    def _indexed_times(self, f, summary) -> dict[str, np.ndarray] | None:
        """Log times of every message per topic from the chunks' message indexes (None when a
        chunk has none: the messages are read instead)."""
        if not summary.chunk_indexes or any(not c.message_index_offsets for c in summary.chunk_indexes):
            return None
        parts: dict[str, list[np.ndarray]] = {}
        for chunk in summary.chunk_indexes:
            for cid, offset in chunk.message_index_offsets.items():
                channel = summary.channels.get(cid)
                if channel is None:
                    return None
                parts.setdefault(str(channel.topic), []).append(self._message_index(f, offset, cid)[:, 0])
        out = {t: np.concatenate(p) for t, p in parts.items() if sum(map(len, p))}
        if any(int(a.max()) >= 2**63 for a in out.values()):
            return None  # log times beyond int64 (a damaged file): explained by the message path
        return {t: np.sort(a.astype(np.int64)) for t, a in out.items()}

    def first_messages(self) -> dict[str, tuple[np.ndarray, Any]]:
        """Log times (ns) and the first decoded message of each topic (times from the message
        indexes where every chunk has them, else from reading every message)."""
        out: dict[str, tuple[np.ndarray, Any]] = {}
        where, what = str(self.path), "read MCAP messages"
        with self._open() as f:
            mc, summary = self._summary(f)
            indexed = self._indexed_times(f, summary)
            if indexed is not None:
                for topic, stamps in indexed.items():
                    out[topic] = (stamps, self._first_decoded(f, topic))
                return out
            f.seek(0)
            mc, _ = self._summary(f)
            times: dict[str, list[int]] = {}
            enc: dict[str, str] = {}
            for _, channel, message in library_iter(where, what, mc.iter_messages()):
                times.setdefault(channel.topic, []).append(message.log_time)
                enc[channel.topic] = channel.message_encoding
            for topic in times:
                msg = self._first_decoded(f, topic, enc[topic] == "json")
                try:  # a damaged file can claim log times beyond int64
                    stamps = np.asarray(times[topic], dtype=np.int64)
                except OverflowError:
                    raise InputError(f"{where}: topic {topic} has log times beyond 64-bit nanoseconds "
                                     "(damaged file?)") from None
                out[topic] = (stamps, msg)
        return out

    def _message_index(self, f, offset: int, cid: int) -> np.ndarray:
        """(n, 2) uint64 (log time, offset in the chunk) of one MessageIndex record."""
        where = str(self.path)
        if not 0 <= offset <= os.path.getsize(where):
            raise InputError(f"{where}: no message index at byte {offset} (outside the file; damaged file?)")
        f.seek(offset)
        head = f.read(15)
        if len(head) != 15 or head[0] != MESSAGE_INDEX_OPCODE or \
                int.from_bytes(head[9:11], "little") != cid:
            raise InputError(f"{where}: no message index at byte {offset} (damaged file?)")
        size = int.from_bytes(head[11:15], "little")
        check_claim(where, f"the message index at byte {offset}", size, 1, os.path.getsize(where))
        raw = f.read(size)
        if len(raw) != size or size % 16:
            raise InputError(f"{where}: the message index at byte {offset} is truncated")
        return np.frombuffer(raw, dtype="<u8").reshape(-1, 2)

    def _chunk(self, f, index) -> np.ndarray:
        """The decompressed records of one chunk (mcap's own chunk reader and codecs), as uint8."""
        from mcap.data_stream import ReadDataStream
        from mcap.records import Chunk
        from mcap.stream_reader import get_chunk_data_stream

        where = str(self.path)
        what = f"read the chunk at byte {index.chunk_start_offset}"
        if not 0 <= index.chunk_start_offset <= os.path.getsize(where) - 9:
            raise InputError(f"{where}: a chunk index points to byte {index.chunk_start_offset}, outside the "
                             "file (damaged summary?)")
        f.seek(index.chunk_start_offset + 9)  # past the record's opcode and length
        chunk = library_call(where, what, Chunk.read, ReadDataStream(f))
        if chunk.uncompressed_size != index.uncompressed_size:  # the size checked is the size read
            raise InputError(f"{where}: the chunk at byte {index.chunk_start_offset} claims "
                             f"{chunk.uncompressed_size} bytes, its index {index.uncompressed_size}")
        stream, size = library_call(where, what, get_chunk_data_stream, chunk)
        return np.frombuffer(library_call(where, what, stream.read, size), dtype=np.uint8)

    def _first_fixed(self, summary, channel, buf: np.ndarray, start: int, extractors: list,
                     total: int) -> FixedTopic:
        """The :class:`FixedTopic` of ``channel``'s topic from the Message record at ``start``
        in ``buf``, decoded by mcap's decoders for the extractors' checks. Every record must
        equal it but for its sequence number, log and publish times and numbers."""
        where, topic = str(self.path), channel.topic
        if start < 0 or start + MESSAGE_PREFIX > buf.size:
            raise NotFixed("an index points outside its chunk")
        prefix = bytes(buf[start:start + MESSAGE_PREFIX])
        size = int.from_bytes(prefix[1:9], "little") - (MESSAGE_PREFIX - 9)
        raw = bytes(buf[start + MESSAGE_PREFIX:start + MESSAGE_PREFIX + max(size, 0)])
        if prefix[0] != MESSAGE_OPCODE or int.from_bytes(prefix[9:11], "little") != channel.id \
                or size < 0 or len(raw) != size:
            raise NotFixed("the index does not point at a Message record of the topic")
        schema = summary.schemas.get(channel.schema_id)
        what = f"read the schema of {topic}"
        decode = next((d for d in (library_call(where, what, factory.decoder_for, channel.message_encoding,
                                                schema) for factory in _decoders()) if d is not None), None)
        if decode is None:
            raise NotFixed(f"no decoder for {topic}")
        decoded = library_call(where, f"decode {topic}", decode, raw)
        varying = np.zeros(MESSAGE_PREFIX, dtype=bool)
        varying[11:] = True  # sequence, log time, publish time
        kind = short_type(schema.name if schema else "")
        return fixed_topic(topic, kind, channel.message_encoding == "cdr", raw, decoded, extractors, total,
                           where, prefix, varying)

    def _first_decoded(self, f, topic: str, as_json: bool | None = None) -> Any:
        """The first message of ``topic`` in log-time order, decoded (JSON by the standard
        library, the rest by mcap's decoders)."""
        where, what = str(self.path), "read MCAP messages"
        f.seek(0)
        mc, summary = self._summary(f)
        if as_json is None:
            as_json = any(c.message_encoding == "json" for c in summary.channels.values() if c.topic == topic)
        if as_json:
            found = next(library_iter(where, what, mc.iter_messages(topics=[topic])), None)
            msg = library_call(where, what, json.loads, found[2].data) if found else None
        else:
            found = next(library_iter(where, what, mc.iter_decoded_messages(topics=[topic])), None)
            msg = found[3] if found else None
        if found is None:
            raise InputError(f"{where}: topic {topic} lost its messages on a second read")
        return msg
