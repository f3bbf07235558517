"""Standalone MCAP files via ``mcap`` and its decoder factories.

Encodings: ``cdr`` with ``ros2msg`` schemas (mcap-ros2-support), ``ros1`` with
``ros1msg`` schemas (mcap-ros1-support), and ``json`` (decoded with the standard
library's json, which is what the encoding is).
"""

from __future__ import annotations

import json
from collections.abc import Sequence
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.library_errors import library_call, library_iter
from ccl_cli.io.limits import check_claim, open_regular
from ccl_cli.io.messages import TopicReader, finish_topics, read_topics
from ccl_cli.io.options import StreamOptions
from ccl_cli.io.sniff import MCAP_MAGIC
from ccl_cli.io.streams import Stream


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
        for index in summary.chunk_indexes:  # what each chunk decompresses to, before it is read
            check_claim(where, f"the chunk at byte {index.chunk_start_offset}",
                        max(int(index.uncompressed_size), int(index.chunk_length)), 1)
        return reader, summary

    def listing(self) -> dict[str, Any]:
        with self._open() as f:
            _, summary = self._summary(f)
        counts = summary.statistics.channel_message_counts if summary.statistics else {}
        topics = {}
        for cid, ch in summary.channels.items():
            schema = summary.schemas.get(ch.schema_id)
            topics[str(ch.topic)] = {"type": schema.name if schema else "", "encoding": ch.message_encoding,
                                     "count": int(counts.get(cid, 0))}
        st = summary.statistics
        return {"start_ns": int(st.message_start_time) if st else 0,
                "end_ns": int(st.message_end_time) if st else 0, "topics": dict(sorted(topics.items()))}

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
                msgtypes[selection.topic] = schema.name if schema else ""
                encodings[selection.topic] = channels[0].message_encoding
            collectors, slots = read_topics(selections, msgtypes, where)
            topics = list(collectors)
            what = f"decode {', '.join(topics)}"
            if all(encodings[t] == "json" for t in topics):
                for _, channel, message in library_iter(where, what, reader.iter_messages(topics=topics)):
                    decoded = library_call(where, what, json.loads, message.data)
                    collectors[channel.topic].add(decoded, message.log_time)
            else:
                for _, channel, message, decoded in library_iter(where, what,
                                                                 reader.iter_decoded_messages(topics=topics)):
                    collectors[channel.topic].add(decoded, message.log_time)
            return finish_topics(collectors, slots)

    def first_messages(self) -> dict[str, tuple[np.ndarray, Any]]:
        """Log times (ns) and the first decoded message of each topic."""
        out: dict[str, tuple[np.ndarray, Any]] = {}
        where, what = str(self.path), "read MCAP messages"
        with self._open() as f:
            mc, _ = self._summary(f)
            times: dict[str, list[int]] = {}
            enc: dict[str, str] = {}
            for _, channel, message in library_iter(where, what, mc.iter_messages()):
                times.setdefault(channel.topic, []).append(message.log_time)
                enc[channel.topic] = channel.message_encoding
            for topic in times:
                f.seek(0)
                mc, _ = self._summary(f)
                if enc[topic] == "json":
                    found = next(library_iter(where, what, mc.iter_messages(topics=[topic])), None)
                    msg = library_call(where, what, json.loads, found[2].data) if found else None
                else:
                    found = next(library_iter(where, what, mc.iter_decoded_messages(topics=[topic])), None)
                    msg = found[3] if found else None
                if found is None:
                    raise InputError(f"{where}: topic {topic} lost its messages on a second read")
                try:  # a damaged file can claim log times beyond int64
                    stamps = np.asarray(times[topic], dtype=np.int64)
                except OverflowError:
                    raise InputError(f"{where}: topic {topic} has log times beyond 64-bit nanoseconds "
                                     "(damaged file?)") from None
                out[topic] = (stamps, msg)
        return out
