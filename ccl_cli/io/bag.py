"""ROS 1 ``.bag`` files and ROS 2 bag directories (sqlite3 or mcap storage), via rosbags.

Old ROS 2 bags carry no message definitions: their types come from the configured
typestore (``typestore: ros2_humble`` by default; any name of ``rosbags.typesys.Stores``).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from ccl_cli.errors import InputError
from ccl_cli.io.streams import Stream, StreamSpec, decoding, finish_topics, read_topics


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


class BagReader:
    """One ROS 1 bag or ROS 2 bag directory."""

    def __init__(self, path: Path, typestore: str | None = None) -> None:
        self.path = Path(path)
        self.typestore = typestore

    def _open(self):
        from rosbags.highlevel import AnyReader

        try:
            reader = AnyReader([bag_root(self.path)], default_typestore=_typestore(self.typestore))
            reader.open()
        except InputError:
            raise
        except Exception as exc:  # rosbags raises several types for corrupt/truncated bags
            raise InputError(f"{self.path}: cannot read bag ({type(exc).__name__}: {exc})") from None
        return reader

    def inspect(self) -> dict[str, Any]:
        reader = self._open()
        try:
            topics = {name: {"type": info.msgtype, "count": int(info.msgcount or 0)}
                      for name, info in sorted(reader.topics.items())}
            return {"start_ns": int(reader.start_time), "end_ns": int(reader.end_time),
                    "topics": topics}
        finally:
            reader.close()

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
                    have = ", ".join(sorted(reader.topics)) or "none"
                    raise InputError(f"{where}: topic {spec.topic!r} not found (topics: {have})")
                msgtypes[spec.topic] = found[0].msgtype
            collectors, slots = read_topics(specs, msgtypes, where)
            conns = [c for c in reader.connections if c.topic in collectors]
            with decoding(where, collectors):
                for conn, log_ns, raw in reader.messages(connections=conns):
                    collectors[conn.topic].add(reader.deserialize(raw, conn.msgtype), log_ns)
            return finish_topics(collectors, slots)
        finally:
            reader.close()
