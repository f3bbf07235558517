"""Fixture writers: recordings written at test time by the third-party writers
(rosbags, mcap, mcap-ros2, csv, h5py) from known arrays. No bytes are typed by hand."""

from __future__ import annotations

import csv
import json
import struct
import zlib
from dataclasses import dataclass
from pathlib import Path

import h5py
import numpy as np

JOINTS = [f"joint_{i}" for i in range(1, 8)]
EPOCH_NS = 1_700_000_000_123_456_789  # beyond float64's exact integers on purpose
MSG = "sensor_msgs/msg/JointState"


@dataclass
class Recording:
    t_ns: np.ndarray  # header stamps (n,)
    log_ns: np.ndarray  # log/receive times (n,)
    position: np.ndarray  # (n, 7)
    velocity: np.ndarray  # (n, 7)
    order: list[list[int]]  # per message, the order of joint names written


def joint_recording(n: int = 50, rate: float = 100.0, gap_after: int | None = None, gap_s: float = 1.0,
                    shuffle: bool = False, jitter: float = 0.0, seed: int = 0) -> Recording:
    rng = np.random.default_rng(seed)
    dt = np.full(n, 1.0 / rate)
    if jitter:
        dt *= 1.0 + rng.uniform(-jitter, jitter, n)
    dt[0] = 0.0
    if gap_after is not None:
        dt[gap_after] += gap_s
    t_s = np.cumsum(dt)
    t_ns = EPOCH_NS + np.round(t_s * 1e9).astype(np.int64)
    phase = np.arange(7)[None, :] * 0.3
    position = np.sin(t_s[:, None] + phase)
    velocity = np.cos(t_s[:, None] + phase)
    order = [list(rng.permutation(7)) if shuffle else list(range(7)) for _ in range(n)]
    return Recording(t_ns, t_ns + 5_000_000, position, velocity, order)


def _typestore(ros1: bool = False):
    from rosbags.typesys import Stores, get_typestore

    return get_typestore(Stores.ROS1_NOETIC if ros1 else Stores.ROS2_HUMBLE)


def _msg(ts, rec: Recording, i: int):
    JointState = ts.types[MSG]
    Header = ts.types["std_msgs/msg/Header"]
    Time = ts.types["builtin_interfaces/msg/Time"]
    o = rec.order[i]
    sec, nsec = divmod(int(rec.t_ns[i]), 1_000_000_000)
    extra = {"seq": i} if "seq" in Header.__dataclass_fields__ else {}  # ROS 1 headers
    return JointState(header=Header(stamp=Time(sec=sec, nanosec=nsec), frame_id="base", **extra),
                      name=[JOINTS[k] for k in o], position=rec.position[i, o].copy(),
                      velocity=rec.velocity[i, o].copy(), effort=np.zeros(0))


def msg_dict(rec: Recording, i: int) -> dict:
    o = rec.order[i]
    sec, nsec = divmod(int(rec.t_ns[i]), 1_000_000_000)
    return {"header": {"stamp": {"sec": sec, "nanosec": nsec}, "frame_id": "base"},
            "name": [JOINTS[k] for k in o], "position": rec.position[i, o].tolist(),
            "velocity": rec.velocity[i, o].tolist(), "effort": []}


def write_ros1_bag(path: Path, rec: Recording, compress: bool = False,
                   extra: tuple[str, np.ndarray, np.ndarray] | None = None) -> Path:
    from rosbags.rosbag1 import Writer

    ts = _typestore(ros1=True)
    writer = Writer(path)
    if compress:
        writer.set_compression(Writer.CompressionFormat.BZ2)
    with writer:
        conn = writer.add_connection("/joint_states", MSG, typestore=ts)
        for i in range(len(rec.t_ns)):
            writer.write(conn, int(rec.log_ns[i]), ts.serialize_ros1(_msg(ts, rec, i), MSG))
        _write_extra(writer, ts, extra, ros1=True)
    return path


def _write_extra(writer, ts, extra, ros1: bool) -> None:
    if extra is None:
        return
    topic, t_ns, values = extra
    kind = "std_msgs/msg/Float64MultiArray"
    Arr = ts.types[kind]
    Layout = ts.types["std_msgs/msg/MultiArrayLayout"]
    conn = writer.add_connection(topic, kind, typestore=ts)
    for t, row in zip(t_ns, values, strict=True):
        msg = Arr(layout=Layout(dim=[], data_offset=0), data=np.asarray(row, dtype=float))
        data = ts.serialize_ros1(msg, kind) if ros1 else ts.serialize_cdr(msg, kind)
        writer.write(conn, int(t), data)


def write_ros2_bag(path: Path, rec: Recording, storage: str = "sqlite3",
                   extra: tuple[str, np.ndarray, np.ndarray] | None = None) -> Path:
    from rosbags.rosbag2 import StoragePlugin, Writer

    ts = _typestore()
    plugin = StoragePlugin.MCAP if storage == "mcap" else StoragePlugin.SQLITE3
    with Writer(path, version=9, storage_plugin=plugin) as writer:
        conn = writer.add_connection("/joint_states", MSG, typestore=ts)
        for i in range(len(rec.t_ns)):
            writer.write(conn, int(rec.log_ns[i]), ts.serialize_cdr(_msg(ts, rec, i), MSG))
        _write_extra(writer, ts, extra, ros1=False)
    return path


def write_mcap_ros2(path: Path, rec: Recording) -> Path:
    from mcap_ros2.writer import Writer

    msgdef, _ = _typestore().generate_msgdef(MSG, ros_version=2)
    with open(path, "wb") as f:
        writer = Writer(f)
        schema = writer.register_msgdef(MSG, msgdef)
        for i in range(len(rec.t_ns)):
            writer.write_message("/joint_states", schema, msg_dict(rec, i),
                                 log_time=int(rec.log_ns[i]), publish_time=int(rec.log_ns[i]))
        writer.finish()
    return path


def write_mcap_ros1(path: Path, rec: Recording) -> Path:
    from mcap.writer import Writer

    ts = _typestore(ros1=True)
    msgdef, _ = ts.generate_msgdef(MSG, ros_version=1)
    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="ros1", library="tests")
        sid = writer.register_schema("sensor_msgs/JointState", "ros1msg", msgdef.encode())
        cid = writer.register_channel("/joint_states", "ros1", sid)
        for i in range(len(rec.t_ns)):
            writer.add_message(cid, int(rec.log_ns[i]), ts.serialize_ros1(_msg(ts, rec, i), MSG),
                               int(rec.log_ns[i]))
        writer.finish()
    return path


def write_mcap_json(path: Path, rec: Recording, messages: list[dict | bytes] | None = None) -> Path:
    """JSON-encoded JointState messages (``messages``: these dicts, or encoded texts, instead of
    ``rec``'s, one per stamp of ``rec``)."""
    from mcap.writer import Writer

    with open(path, "wb") as f:
        writer = Writer(f)
        writer.start(profile="", library="tests")
        sid = writer.register_schema("sensor_msgs/JointState", "jsonschema",
                                     json.dumps({"type": "object"}).encode())
        cid = writer.register_channel("/joint_states", "json", sid)
        for i in range(len(rec.t_ns)):
            msg = msg_dict(rec, i) if messages is None else messages[i]
            raw = msg if isinstance(msg, bytes) else json.dumps(msg).encode()
            writer.add_message(cid, int(rec.log_ns[i]), raw, int(rec.log_ns[i]))
        writer.finish()
    return path


def write_csv(path: Path, rec: Recording, duplicate_names: bool = True) -> Path:
    """A rosbag-export-like CSV: %time (int ns), position x,y,z then orientation x,y,z,w."""
    header = ["%time", "x", "y", "z", "x", "y", "z", "w"] if duplicate_names else \
        ["%time", "px", "py", "pz", "ox", "oy", "oz", "ow"]
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(header)
        for i in range(len(rec.t_ns)):
            w.writerow([int(rec.t_ns[i]), *map(repr, rec.position[i].tolist())])
    return path


MATLAB_HEADER = (b"MATLAB 7.3 MAT-file, Platform: GLNXA64, Created on: Mon Nov 30 12:00:00 2026 "
                 b"HDF5 schema 1.00 .")


class Cell(list):
    """A cell array for :func:`write_mat73` whose cells may hold structs (dicts), arrays or numbers
    (``proc_data``: a 1×D cell of structs, one demonstration per cell)."""


def write_mat73(path: Path, variables: dict) -> Path:
    """MATLAB's v7.3 layout written with h5py. Values are in MATLAB's orientation:
    arrays (stored transposed; a number as 1×1), lists (cell arrays of arrays), dicts
    (structs), :class:`Cell` (cells of anything, structs included, stored in ``#refs#``)."""

    def put(parent, refs, name, value):
        if isinstance(value, Cell):
            rs = []
            for k, item in enumerate(value):
                key = f"{name}_{k}_{len(refs)}"
                put(refs, refs, key, item)
                rs.append(refs[key].ref)
            ds = parent.create_dataset(name, data=np.array(rs, dtype=h5py.ref_dtype).reshape(len(rs), 1))
            ds.attrs["MATLAB_class"] = np.bytes_("cell")
        elif isinstance(value, list) and isinstance(value[0], dict):  # struct array: a field = references
            g = parent.create_group(name)
            g.attrs["MATLAB_class"] = np.bytes_("struct")
            for key in value[0]:
                rs = []
                for k, elem in enumerate(value):
                    ds = refs.create_dataset(f"{name}_{key}_{k}", data=np.asarray(elem[key], dtype=float).T)
                    ds.attrs["MATLAB_class"] = np.bytes_("double")
                    rs.append(ds.ref)
                g.create_dataset(key, data=np.array(rs, dtype=h5py.ref_dtype).reshape(len(rs), 1))
        elif isinstance(value, list):
            rs = []
            for k, item in enumerate(value):
                ds = refs.create_dataset(f"{name}_{k}_{len(refs)}", data=np.asarray(item).T)
                ds.attrs["MATLAB_class"] = np.bytes_("double")
                rs.append(ds.ref)
            ds = parent.create_dataset(name, data=np.array(rs, dtype=h5py.ref_dtype).reshape(len(rs), 1))
            ds.attrs["MATLAB_class"] = np.bytes_("cell")
        elif isinstance(value, dict):
            g = parent.create_group(name)
            g.attrs["MATLAB_class"] = np.bytes_("struct")
            for key, v in value.items():
                put(g, refs, key, v)
        elif isinstance(value, str):
            ds = parent.create_dataset(name, data=np.frombuffer(value.encode("utf-16-le"), np.uint16)[None].T)
            ds.attrs["MATLAB_class"] = np.bytes_("char")
        else:
            arr = np.asarray(value, dtype=float)
            ds = parent.create_dataset(name, data=(arr.reshape(1, 1) if arr.ndim == 0 else arr).T)
            ds.attrs["MATLAB_class"] = np.bytes_("double")

    with h5py.File(path, "w", userblock_size=512) as f:
        refs = f.create_group("#refs#")
        for name, value in variables.items():
            put(f, refs, name, value)
    with open(path, "r+b") as fh:  # MATLAB's header: 116 bytes text, subsys offset, version, endian
        fh.write(MATLAB_HEADER.ljust(116, b" ") + b"\x00" * 8 + b"\x00\x02" + b"IM")
    return path


WRITERS = {
    "ros1": lambda p, r: write_ros1_bag(p / "rec.bag", r),
    "ros1-bz2": lambda p, r: write_ros1_bag(p / "rec.bag", r, compress=True),
    "ros2-sqlite3": lambda p, r: write_ros2_bag(p / "rec_bag", r, "sqlite3"),
    "ros2-mcap": lambda p, r: write_ros2_bag(p / "rec_bag", r, "mcap"),
    "mcap-ros2": lambda p, r: write_mcap_ros2(p / "rec.mcap", r),
    "mcap-ros1": lambda p, r: write_mcap_ros1(p / "rec.mcap", r),
    "mcap-json": lambda p, r: write_mcap_json(p / "rec.mcap", r),
}


def pad_compressed_mat(path: Path, name: str, extra: int) -> None:
    """Append ``extra`` zero bytes to the data of variable ``name`` of a compressed v7 file
    scipy wrote, keeping its declared shape: what a zlib bomb does (zeros deflate ~1000:1)."""
    from ccl_cli.io.formats.mat5_elements import _element, _name

    raw = path.read_bytes()
    out, pos = bytearray(raw[:128]), 128
    while pos < len(raw):
        mtype, nbytes = struct.unpack_from("<II", raw, pos)
        element = raw[pos + 8:pos + 8 + nbytes]
        pos += 8 + nbytes
        inner = zlib.decompress(element)
        if _name(inner, "<") == name:
            at = 8
            for _ in range(3):  # array flags, dimensions, name: then the real part
                _, _, at = _element(inner, at, "<")
            ptype, pbytes = struct.unpack_from("<II", inner, at)
            deflater, zeros = zlib.compressobj(), bytes(min(extra, 1 << 24))
            element = deflater.compress(struct.pack("<II", 14, len(inner) - 8 + extra) + inner[8:at]
                                        + struct.pack("<II", ptype, pbytes + extra)
                                        + inner[at + 8:at + 8 + pbytes])
            for start in range(0, extra, len(zeros)):  # never the whole padding in memory
                element += deflater.compress(zeros[:extra - start])
            element += deflater.compress(inner[at + 8 + pbytes:]) + deflater.flush()
        out += struct.pack("<II", mtype, len(element)) + element
    path.write_bytes(bytes(out))
