"""Standalone MCAP files via ``mcap`` and its decoder factories.

Encodings: ``cdr`` with ``ros2msg`` schemas (mcap-ros2-support), ``ros1`` with
``ros1msg`` schemas (mcap-ros1-support), and ``json`` (decoded with the standard
library's json, which is what the encoding is).
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any

from ccl_cli.errors import InputError
from ccl_cli.io.streams import Stream, StreamSpec, finish_topics, library_call, library_iter, read_topics


def _decoders():
    from mcap_ros1.decoder import DecoderFactory as Ros1Decoders
    from mcap_ros2.decoder import DecoderFactory as Ros2Decoders

    return [Ros2Decoders(), Ros1Decoders()]


MAGIC = b"\x89MCAP"


class McapReader:
    """One standalone MCAP file (refused at once if it does not start with the MCAP magic)."""

    def __init__(self, path: Path) -> None:
        self.path = Path(path)

    def _open(self):
        where = str(self.path)
        try:
            f = open(self.path, "rb")
        except OSError as exc:
            raise InputError(f"{where}: {exc.strerror}") from None
        if f.read(len(MAGIC)) != MAGIC:
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
        return reader, summary

    def inspect(self) -> dict[str, Any]:
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

    def read(self, spec: StreamSpec) -> Stream:
        return self.read_many([spec])[0]

    def read_many(self, specs: list[StreamSpec]) -> list[Stream]:
        """Several streams in one pass over the file (each message decoded once), in log-time
        order. (Reading in file order instead makes mcap hold the file's data in memory:
        measured 84 MB for 100k JointState messages against 3 MB in log-time order.)"""
        where = str(self.path)
        with self._open() as f:
            reader, summary = self._summary(f)
            msgtypes, encodings = {}, {}
            for spec in specs:
                channels = [c for c in summary.channels.values() if c.topic == spec.topic]
                if not channels:
                    have = ", ".join(sorted({str(c.topic) for c in summary.channels.values()})) or "none"
                    raise InputError(f"{where}: topic {spec.topic!r} not found (topics: {have})")
                schema = summary.schemas.get(channels[0].schema_id)
                msgtypes[spec.topic] = schema.name if schema else ""
                encodings[spec.topic] = channels[0].message_encoding
            collectors, slots = read_topics(specs, msgtypes, where)
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
