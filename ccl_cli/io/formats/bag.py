"""ROS 1 ``.bag`` files and ROS 2 bag directories (sqlite3 or mcap storage), via rosbags.

Old ROS 2 bags carry no message definitions: their types come from the configured
typestore (``typestore: ros2_humble`` by default; any name of ``rosbags.typesys.Stores``).
"""

from __future__ import annotations

import logging
from collections.abc import Sequence
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.io.formats.bag1 import BagIndex, in_order, read_chunk, read_index
from ccl_cli.io.layouts import NotFixed, fixed_topic, read_uint
from ccl_cli.io.library_errors import library_call, library_iter
from ccl_cli.io.limits import OutsideFile, inside, open_regular, regular_file
from ccl_cli.io.messages import TopicReader, finish_topics, read_topics, short_type, type_name
from ccl_cli.io.options import StreamOptions
from ccl_cli.io.sniff import BAG2_METADATA
from ccl_cli.io.streams import Stream
from ccl_cli.io.yamlsafe import read_yaml
from ccl_cli.progress import progress_of

log = logging.getLogger("ccl")
_TYPES = "\0types"  # the key of the topic types among the topics read by _fixed_topics


def _typestore(name: str | None):
    from rosbags.typesys import Stores, get_typestore

    key = (name or "ros2_humble").upper()
    try:
        return get_typestore(Stores[key])
    except KeyError:
        known = ", ".join(s.name.lower() for s in Stores)
        raise InputError(f"unknown typestore {name!r} (known: {known})") from None


def bag_root(path: Path) -> Path:
    """The path rosbags opens: the .bag file, or the ROS 2 bag directory."""
    if path.is_dir():
        return path
    if path.name == BAG2_METADATA or path.suffix in (".db3", ".mcap") and \
            (path.parent / BAG2_METADATA).exists():
        return path.parent
    return path


def storage_files(root: Path, metadata: Any, allow_outside: bool = False) -> list[Path]:
    """The storage files a ROS 2 bag's metadata names (``relative_file_paths``, and the
    ``files`` entries of newer versions), each checked before rosbags opens it: inside the
    bag folder once ``..`` and symlinks are resolved (unless ``allow_outside``; a symlink
    followed is reported) and a regular file (a FIFO would block the open forever)."""
    where = str(root / BAG2_METADATA)
    info = metadata.get("rosbag2_bagfile_information") if isinstance(metadata, dict) else None
    if not isinstance(info, dict):
        return []  # rosbags explains what is missing
    names = info.get("relative_file_paths") or []
    files = info.get("files") or []
    if not isinstance(names, list) or not isinstance(files, list):
        raise InputError(f"{where}: relative_file_paths and files must be lists")
    names = [*names, *(e.get("path") for e in files if isinstance(e, dict))]
    bad = next((n for n in names if not isinstance(n, str) or not n), None)
    if bad is not None or not all(isinstance(n, str) for n in names):
        raise InputError(f"{where}: a storage file name must be a non-empty string, got {bad!r}"[:200])
    out = []
    for name in dict.fromkeys(names):
        full = inside(root, name, where, allow_outside)
        if full.exists() or full.is_symlink():  # missing ones: rosbags explains
            regular_file(full, "a storage file of the bag")
        if root.resolve() not in full.parents:
            log.warning("%s: %s leads to %s, outside the bag (followed: data.allow_outside)",
                        where, name, full)
        out.append(full)
    return out


def bag_metadata(root: Path, allow_outside: bool = False) -> Any:
    """A ROS 2 bag's metadata.yaml, read by ccl's bounded YAML parser (rosbags' is not bounded);
    a metadata.yaml that is a symlink leading outside the bag folder is refused unless
    ``allow_outside``, as a storage file would be."""
    inside(root, BAG2_METADATA, f"the bag {root}", allow_outside)
    metadata, _ = read_yaml(root / BAG2_METADATA, "ROS 2 bag metadata", error=InputError)
    return metadata


def _count(value, where: str) -> int:
    """A count or time from bag metadata (metadata.yaml can hold anything)."""
    if value is None:
        return 0
    if not isinstance(value, int) or isinstance(value, bool) or not -(2**63) <= value < 2**63:
        raise InputError(f"{where}: bag metadata holds {value!r} where a count or time is expected"[:200])
    return int(value)


class BagReader(TopicReader):
    """One ROS 1 bag or ROS 2 bag directory (the typestore: ``typestore`` of the options)."""

    format = "bag"

    def _open(self):
        from rosbags.highlevel import AnyReader

        where = str(self.path)
        typestore = _typestore(self.options.typestore)
        root = bag_root(self.path)
        if root.is_dir():
            # bounded first (size, depth, aliases): rosbags' YAML parser is not
            metadata = bag_metadata(root, self.options.allow_outside)
            storage_files(root, metadata, self.options.allow_outside)
        else:
            regular_file(root, "the bag")
        reader = library_call(where, "read bag", AnyReader, [root], default_typestore=typestore)
        library_call(where, "read bag", reader.open)
        for conn in reader.connections:  # metadata.yaml is the bag's own text: names typed here
            if not isinstance(conn.topic, str) or not isinstance(conn.msgtype, str):
                library_call(where, "close bag", reader.close)
                raise InputError(f"{where}: a connection's topic or message type is not a string "
                                 f"({type(conn.topic).__name__}, {type(conn.msgtype).__name__}); "
                                 "damaged bag metadata?")
        return reader

    def _index(self) -> BagIndex | None:
        """The index of a ROS 1 bag read with NumPy (:mod:`ccl_cli.io.formats.bag1`); None for
        a ROS 2 bag or a bag whose index this does not read (rosbags' reader then explains)."""
        root = bag_root(self.path)
        if root.suffix != ".bag" or not root.is_file():
            return None
        try:
            index = read_index(root)
        except OutsideFile:
            raise  # a chunk or index position outside the file: damaged, whoever reads it
        except InputError:
            return None
        return index if set(index.entries) == {c.id for c in index.connections} else None

    def listing(self) -> dict[str, Any]:
        index = self._index()
        if index is not None and index.entries:  # from the index: no message read
            topics: dict[str, dict[str, Any]] = {}
            for conn in index.connections:
                entry = topics.setdefault(conn.topic, {"type": type_name(conn.msgtype), "count": 0})
                entry["count"] += int(len(index.entries[conn.id]))
            times = [e[[0, -1], 0] for e in index.entries.values() if len(e)]
            codecs = sorted({c.compression or "none" for c in index.chunks}) or ["none"]
            return {"start_ns": int(min(t[0] for t in times)), "end_ns": int(max(t[1] for t in times)),
                    "storage": f"ROS 1 bag 2.0, {len(index.chunks)} chunk(s)",
                    "compression": ", ".join(codecs), "encoding": "ros1",
                    "topics": dict(sorted(topics.items()))}
        reader = self._open()
        try:
            where = str(self.path)
            items = library_call(where, "read bag metadata", lambda: sorted(reader.topics.items()))
            topics = {name: {"type": str(info.msgtype), "count": _count(info.msgcount, where)}
                      for name, info in items}
            start, end = library_call(where, "read bag metadata",
                                      lambda: (reader.start_time, reader.end_time))
            return {"start_ns": _count(start, where), "end_ns": _count(end, where), "topics": topics,
                    **self._container()}
        finally:
            library_call(str(self.path), "close bag", reader.close)

    def _container(self) -> dict[str, str]:
        """Storage, compression and message encoding of a ROS 2 bag (its metadata.yaml) or of a
        ROS 1 bag rosbags opened; what the metadata does not say is left out."""
        root = bag_root(self.path)
        if not root.is_dir():
            return {"storage": "ROS 1 bag", "encoding": "ros1"}
        metadata = bag_metadata(root, self.options.allow_outside)
        info = metadata.get("rosbag2_bagfile_information") if isinstance(metadata, dict) else None
        if not isinstance(info, dict):
            return {}
        mode = str(info.get("compression_mode") or "").lower()
        codec = str(info.get("compression_format") or "none")
        out = {"storage": f"ROS 2 bag ({info.get('storage_identifier') or 'storage not named'}, "
                          f"version {info.get('version', '?')})",
               "compression": codec + (f" per {mode}" if mode else "")}
        formats = {t.get("topic_metadata", {}).get("serialization_format") for t in
                   info.get("topics_with_message_count") or [] if isinstance(t, dict)}
        formats = sorted(str(f) for f in formats if f)
        if formats:
            out["encoding"] = ", ".join(formats)
        return {k: str(v) for k, v in out.items()}

    def streams(self, selections: Sequence[StreamOptions]) -> list[Stream]:
        """Several streams in one pass over the bag (each message deserialised once); topics
        of fixed-layout messages in a ROS 1 bag are gathered from the chunks with NumPy
        (:meth:`_fixed`), the others decoded message by message."""
        where = str(self.path)
        done = self._fixed_topics(selections)
        if done is not None and all(s.topic in done for s in selections):
            _, slots = read_topics(list(selections), done.pop(_TYPES), where)
            return finish_topics({}, slots, done)
        done = {} if done is None else {t: v for t, v in done.items() if t != _TYPES}
        reader = self._open()
        try:
            msgtypes = {}
            for selection in selections:
                found = [c for c in reader.connections if c.topic == selection.topic]
                if not found:
                    have = ", ".join(sorted(map(str, reader.topics))) or "none"
                    raise InputError(f"{where}: topic {selection.topic!r} not found (topics: {have})")
                msgtypes[selection.topic] = str(found[0].msgtype)
            collectors, slots = read_topics(selections, msgtypes, where)
            collectors = {t: c for t, c in collectors.items() if t not in done}
            conns = [c for c in reader.connections if c.topic in collectors]
            what = f"decode {', '.join(collectors)}"
            for conn, log_ns, raw in library_iter(where, what, reader.messages(connections=conns)):
                msg = library_call(where, what, reader.deserialize, raw, conn.msgtype)
                collectors[conn.topic].add(msg, log_ns)
            return finish_topics(collectors, slots, done)
        finally:
            library_call(str(self.path), "close bag", reader.close)

    def _fixed_topics(self, selections: Sequence[StreamOptions]) -> dict[str, Any] | None:
        """The topics of a ROS 1 bag whose messages are all laid out alike, read from the
        chunks with NumPy ({topic: streams}, and under ``_TYPES`` the type of every topic);
        None for a ROS 2 bag, a bag whose index this does not read, or an unknown topic
        (the library path then explains)."""
        index = self._index()
        if index is None:
            return None  # ROS 2 bags, and whatever the library path refuses with its own words
        where = str(self.path)
        types = {c.topic: type_name(c.msgtype) for c in index.connections}
        if any(s.topic not in types for s in selections):
            return None
        collectors, _ = read_topics(list(selections), types, where)
        done: dict[str, Any] = {_TYPES: types}
        with open_regular(bag_root(self.path), "the bag") as f:
            for topic, collector in collectors.items():
                streams = self._fixed(f, index, topic, collector.extractors)
                if streams is not None:
                    done[topic] = streams
        return done

    def _fixed(self, f, index: BagIndex, topic: str, extractors: list) -> list[Stream] | None:
        """The streams of ``topic`` gathered from the chunks (:mod:`ccl_cli.io.layouts`), or None
        when its messages are not all laid out alike."""
        where = str(self.path)
        conns = [c for c in index.connections if c.topic == topic]
        entries = index.entries.get(conns[0].id) if len(conns) == 1 else None
        if entries is None or not entries.size or not conns[0].msgdef:
            return None
        conn = conns[0]
        by_chunk = entries  # in file order: chunk, then place in the chunk
        if not in_order(entries[:, 1:]):
            by_chunk = entries[np.lexsort((entries[:, 2], entries[:, 1]))]
        bounds = np.r_[0, np.flatnonzero(np.diff(by_chunk[:, 1])) + 1, len(by_chunk)]
        numbers = by_chunk[bounds[:-1], 1]
        try:
            first = self._first_message(f, index, conn, entries[0])
            if first is None:
                return None
            head, raw, msg = first
            at = head.find(b"time=")
            if at < 0 or head.find(b"op=\x02") < 0:
                return None
            # a record: header length, header (its time varies), data length, then the message
            record_head = len(head).to_bytes(4, "little") + head + len(raw).to_bytes(4, "little")
            varying = np.zeros(len(record_head), dtype=bool)
            varying[4 + at + 5:4 + at + 13] = True
            gathered = fixed_topic(topic, short_type(conn.msgtype), False, raw, msg, extractors,
                                   len(entries), where, record_head, varying)
            total = sum(index.chunks[int(k)].size for k in numbers)
            with progress_of(f"reading {topic}", total) as advance:
                for k, lo, hi in zip(numbers, bounds[:-1], bounds[1:], strict=True):
                    chunk = index.chunks[int(k)]
                    gathered.add(read_chunk(f, chunk, where), by_chunk[lo:hi, 2], by_chunk[lo:hi, 0])
                    advance(chunk.size)
        except NotFixed:
            return None
        return gathered.finish()

    def _first_message(self, f, index: BagIndex, conn, entry: np.ndarray
                       ) -> tuple[bytes, bytes, Any] | None:
        """Record header, serialised data and rosbags' decoding (with the bag's own message
        definition) of the message at ``entry``; None when it is not a plain message record."""
        from rosbags.typesys import Stores, get_types_from_msg, get_typestore

        where = str(self.path)
        buf = read_chunk(f, index.chunks[int(entry[1])], where)
        at = int(entry[2])
        if at + 8 > buf.size:
            return None
        hlen = int(read_uint(buf, np.array([at]), 4)[0])
        if at + 8 + hlen > buf.size:
            return None
        size = int(read_uint(buf, np.array([at + 4 + hlen]), 4)[0])
        head = bytes(buf[at + 4:at + 4 + hlen])
        raw = bytes(buf[at + 8 + hlen:at + 8 + hlen + size])
        if len(raw) != size:
            return None
        msgtype = type_name(conn.msgtype)
        store = get_typestore(Stores.EMPTY)
        what = f"read the message definition of {conn.topic}"
        library_call(where, what, store.register, library_call(where, what, get_types_from_msg, conn.msgdef,
                                                               msgtype))
        msg = library_call(where, f"decode {conn.topic}", store.deserialize_ros1, raw, msgtype)
        return head, raw, msg

    def first_messages(self) -> dict[str, tuple[np.ndarray, Any]]:
        """Log times (ns) of every message and the first message (decoded) of each topic: for
        a ROS 1 bag from its index (one message decoded per topic), else from every message."""
        index = self._index()
        if index is not None and index.entries:
            out = {}
            with open_regular(bag_root(self.path), "the bag") as f:
                for topic in dict.fromkeys(c.topic for c in index.connections):
                    conns = [c for c in index.connections if c.topic == topic and len(index.entries[c.id])]
                    if not conns:
                        continue
                    times = np.sort(np.concatenate([index.entries[c.id][:, 0] for c in conns]))
                    conn = min(conns, key=lambda c: tuple(index.entries[c.id][0]))
                    first = self._first_message(f, index, conn, index.entries[conn.id][0]) \
                        if conn.msgdef else None
                    if first is None:
                        break  # not a plain message record: rosbags' reader below
                    out[topic] = (times, first[2])
                else:
                    return out
        bag = self._open()
        try:
            times: dict[str, list[int]] = {}
            first: dict[str, Any] = {}
            where, what = str(self.path), "decode the bag's messages"
            for conn, log_ns, raw in library_iter(where, what, bag.messages()):
                times.setdefault(conn.topic, []).append(log_ns)
                if conn.topic not in first:
                    first[conn.topic] = library_call(where, what, bag.deserialize, raw, conn.msgtype)
            return {k: (np.asarray(v, dtype=np.int64), first.get(k)) for k, v in times.items()}
        finally:
            bag.close()
