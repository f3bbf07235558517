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
from ccl_cli.io.library_errors import library_call, library_iter
from ccl_cli.io.limits import inside, regular_file
from ccl_cli.io.messages import TopicReader, finish_topics, read_topics
from ccl_cli.io.options import StreamOptions
from ccl_cli.io.sniff import BAG2_METADATA
from ccl_cli.io.streams import Stream
from ccl_cli.io.yamlsafe import read_yaml

log = logging.getLogger("ccl")


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
            metadata, _ = read_yaml(root / BAG2_METADATA, "ROS 2 bag metadata", error=InputError)
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

    def listing(self) -> dict[str, Any]:
        reader = self._open()
        try:
            where = str(self.path)
            items = library_call(where, "read bag metadata", lambda: sorted(reader.topics.items()))
            topics = {name: {"type": str(info.msgtype), "count": _count(info.msgcount, where)}
                      for name, info in items}
            start, end = library_call(where, "read bag metadata",
                                      lambda: (reader.start_time, reader.end_time))
            return {"start_ns": _count(start, where), "end_ns": _count(end, where), "topics": topics}
        finally:
            library_call(str(self.path), "close bag", reader.close)

    def streams(self, selections: Sequence[StreamOptions]) -> list[Stream]:
        """Several streams in one pass over the bag (each message deserialised once)."""
        where = str(self.path)
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
            conns = [c for c in reader.connections if c.topic in collectors]
            what = f"decode {', '.join(collectors)}"
            for conn, log_ns, raw in library_iter(where, what, reader.messages(connections=conns)):
                msg = library_call(where, what, reader.deserialize, raw, conn.msgtype)
                collectors[conn.topic].add(msg, log_ns)
            return finish_topics(collectors, slots)
        finally:
            library_call(str(self.path), "close bag", reader.close)

    def first_messages(self) -> dict[str, tuple[np.ndarray, Any]]:
        """Log times (ns) of every message and the first message (decoded) of each topic."""
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
