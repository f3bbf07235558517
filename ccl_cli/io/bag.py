"""ROS 1 ``.bag`` files and ROS 2 bag directories (sqlite3 or mcap storage), via rosbags.

Old ROS 2 bags carry no message definitions: their types come from the configured
typestore (``typestore: ros2_humble`` by default; any name of ``rosbags.typesys.Stores``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ccl_cli.errors import InputError
from ccl_cli.io.streams import Stream, StreamSpec, finish_topics, library_call, library_iter, read_topics


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
    if path.name == "metadata.yaml" or path.suffix in (".db3", ".mcap") and \
            (path.parent / "metadata.yaml").exists():
        return path.parent
    return path


def _count(value, where: str) -> int:
    """A count or time from bag metadata (metadata.yaml can hold anything)."""
    if value is None:
        return 0
    if not isinstance(value, int) or isinstance(value, bool) or not -(2**63) <= value < 2**63:
        raise InputError(f"{where}: bag metadata holds {value!r} where a count or time is expected"[:200])
    return int(value)


class BagReader:
    """One ROS 1 bag or ROS 2 bag directory."""

    def __init__(self, path: Path, typestore: str | None = None) -> None:
        self.path = Path(path)
        self.typestore = typestore

    def _open(self):
        from rosbags.highlevel import AnyReader

        where = str(self.path)
        typestore = _typestore(self.typestore)
        root = bag_root(self.path)
        if root.is_dir() and (root / "metadata.yaml").is_file():
            # bounded first (size, depth, aliases): rosbags' YAML parser is not
            from ccl_cli.config import read_yaml

            read_yaml(root / "metadata.yaml", "ROS 2 bag metadata", error=InputError)
        reader = library_call(where, "read bag", AnyReader, [bag_root(self.path)],
                              default_typestore=typestore)
        library_call(where, "read bag", reader.open)
        for conn in reader.connections:  # metadata.yaml is the bag's own text: names typed here
            if not isinstance(conn.topic, str) or not isinstance(conn.msgtype, str):
                library_call(where, "close bag", reader.close)
                raise InputError(f"{where}: a connection's topic or message type is not a string "
                                 f"({type(conn.topic).__name__}, {type(conn.msgtype).__name__}); "
                                 "damaged bag metadata?")
        return reader

    def inspect(self) -> dict[str, Any]:
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

    def read(self, spec: StreamSpec) -> Stream:
        return self.read_many([spec])[0]

    def read_many(self, specs: list[StreamSpec]) -> list[Stream]:
        """Several streams in one pass over the bag (each message deserialised once)."""
        where = str(self.path)
        reader = self._open()
        try:
            msgtypes = {}
            for spec in specs:
                found = [c for c in reader.connections if c.topic == spec.topic]
                if not found:
                    have = ", ".join(sorted(map(str, reader.topics))) or "none"
                    raise InputError(f"{where}: topic {spec.topic!r} not found (topics: {have})")
                msgtypes[spec.topic] = str(found[0].msgtype)
            collectors, slots = read_topics(specs, msgtypes, where)
            conns = [c for c in reader.connections if c.topic in collectors]
            what = f"decode {', '.join(collectors)}"
            for conn, log_ns, raw in library_iter(where, what, reader.messages(connections=conns)):
                msg = library_call(where, what, reader.deserialize, raw, conn.msgtype)
                collectors[conn.topic].add(msg, log_ns)
            return finish_topics(collectors, slots)
        finally:
            library_call(str(self.path), "close bag", reader.close)
