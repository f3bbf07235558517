"""Fixed-layout messages gathered with NumPy (ccl_cli.io.layouts) against the libraries'
decoding of every message: files written by rosbags / mcap writers, read by ccl's chunk
path and by rosbags / mcap-ros1 / mcap-ros2 decoders message by message."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import pytest
from writers import JOINTS, WRITERS, joint_recording

import ccl_cli.io.layouts as layouts
from ccl_cli.io import StreamOptions, load_demonstrations
from ccl_cli.io.formats.bag import BagReader
from ccl_cli.io.formats.mcap import McapReader
from ccl_cli.io.options import DataOptions

FAST = ["ros1", "ros1-bz2", "mcap-ros1", "mcap-ros2"]


@pytest.fixture
def gathered(monkeypatch):
    """The topics the NumPy path finished (a list, filled as files are read)."""
    seen: list[str] = []
    finish = layouts.FixedTopic.finish

    def spy(self):
        seen.append(self.topic)
        return finish(self)

    monkeypatch.setattr(layouts.FixedTopic, "finish", spy)
    return seen


def _library_joint_states(path: Path, container: str) -> tuple[np.ndarray, ...]:
    """Header stamps, log times, position and velocity of every message, decoded one by one
    by the libraries (joint order as written)."""
    stamps, logs, pos, vel = [], [], [], []
    if container.startswith("ros1"):
        from rosbags.highlevel import AnyReader

        with AnyReader([path]) as r:
            for conn, log, raw in r.messages():
                m = r.deserialize(raw, conn.msgtype)
                stamps.append(m.header.stamp.sec * 10**9 + m.header.stamp.nanosec)
                logs.append(log)
                pos.append(m.position)
                vel.append(m.velocity)
    else:
        from mcap.reader import make_reader
        from mcap_ros1.decoder import DecoderFactory as D1
        from mcap_ros2.decoder import DecoderFactory as D2

        with open(path, "rb") as f:
            for _, _, msg, m in make_reader(f, decoder_factories=[D2(), D1()]).iter_decoded_messages():
                s = m.header.stamp
                sec = s.sec if hasattr(s, "sec") else s.secs
                stamps.append(sec * 10**9 + (s.nanosec if hasattr(s, "nanosec") else s.nsecs))
                logs.append(msg.log_time)
                pos.append(m.position)
                vel.append(m.velocity)
    return np.array(stamps), np.array(logs), np.array(pos, dtype=float), np.array(vel, dtype=float)


@pytest.mark.parametrize("container", FAST)
def test_joint_states_equal_the_libraries_decoding(tmp_path, container, gathered):
    rec = joint_recording(n=6000, jitter=0.3, seed=3)  # several chunks, irregular stamps
    path = WRITERS[container](tmp_path, rec)
    reader_cls = BagReader if container.startswith("ros1") else McapReader
    options = DataOptions.model_validate({"state": {"topic": "/joint_states", "field": "position"}})
    sel = [StreamOptions.model_validate({"topic": "/joint_states", "field": f, "stamp": stamp})
           for f, stamp in (("position", "header"), ("velocity", "log"))]
    streams = reader_cls(path, options).streams(sel)
    assert gathered == ["/joint_states"]
    stamps, logs, pos, vel = _library_joint_states(path, container)
    np.testing.assert_array_equal(streams[0].t_ns, stamps)
    np.testing.assert_array_equal(streams[1].t_ns, logs)
    np.testing.assert_array_equal(streams[0].values, pos)
    np.testing.assert_array_equal(streams[1].values, vel)
    np.testing.assert_array_equal(streams[0].values, rec.position)  # and the truth written
    assert streams[0].names == [f"{j}.position" for j in JOINTS]  # named by the messages' joints
    assert streams[0].meta["stamp"] == "header" and streams[1].meta["stamp"] == "log"


@pytest.mark.parametrize("container", FAST)
def test_loader_on_the_numpy_path_matches_the_message_path(tmp_path, container, gathered, monkeypatch):
    rec = joint_recording(n=3000, gap_after=1500, seed=5)
    path = WRITERS[container](tmp_path, rec)
    cfg = {"files": [str(path)],
           "state": {"topic": "/joint_states", "field": "position", "joints": JOINTS[::-1]},
           "action": {"topic": "/joint_states", "field": "velocity", "joints": JOINTS[2:5]}}
    fast = load_demonstrations(cfg)
    assert gathered == ["/joint_states"]
    np.testing.assert_array_equal(fast.X, rec.position[:, ::-1])
    monkeypatch.setattr(layouts, "WALKS", {})  # every topic message by message
    gathered.clear()
    slow = load_demonstrations(cfg)
    assert gathered == []
    for key in ("X", "U", "t", "demo"):
        np.testing.assert_array_equal(getattr(fast, key), getattr(slow, key))
    assert fast.state_names == slow.state_names and fast.action_names == slow.action_names


@pytest.mark.parametrize("container", ["ros1", "mcap-ros2"])
def test_joint_names_changing_order_fall_back_and_stay_exact(tmp_path, container, gathered):
    rec = joint_recording(n=2000, shuffle=True, seed=1)
    path = WRITERS[container](tmp_path, rec)
    cfg = {"files": [str(path)], "state": {"topic": "/joint_states", "field": "position", "joints": JOINTS},
           "action": {"topic": "/joint_states", "field": "velocity", "joints": JOINTS}}
    d = load_demonstrations(cfg)
    assert gathered == []  # the names differ between messages: decoded message by message
    np.testing.assert_array_equal(d.X, rec.position)
    np.testing.assert_array_equal(d.U, rec.velocity)


# -- other fixed-layout types, written by rosbags (ROS 1 bag) and as CDR in an MCAP ------------
def _messages(ts, kind: str, n: int, rng) -> tuple[list, np.ndarray]:
    """n messages of ``kind`` and the numbers each holds in the order ccl reads them."""
    T = ts.types
    Header, Time = T["std_msgs/msg/Header"], T["builtin_interfaces/msg/Time"]
    ros1 = "seq" in Header.__dataclass_fields__
    geo = "geometry_msgs/msg/"
    V3, Pt, Q = T[geo + "Vector3"], T[geo + "Point"], T[geo + "Quaternion"]
    vals = rng.normal(size=(n, 7))
    msgs = []
    for i, v in enumerate(vals):
        seq = {"seq": i} if ros1 else {}
        head = Header(stamp=Time(sec=100 + i, nanosec=7 * i), frame_id="world", **seq)
        if kind == "PoseStamped":
            msgs.append(T["geometry_msgs/msg/PoseStamped"](header=head, pose=T["geometry_msgs/msg/Pose"](
                position=Pt(x=v[0], y=v[1], z=v[2]), orientation=Q(x=v[3], y=v[4], z=v[5], w=v[6]))))
        elif kind == "TwistStamped":
            msgs.append(T["geometry_msgs/msg/TwistStamped"](header=head, twist=T["geometry_msgs/msg/Twist"](
                linear=V3(x=v[0], y=v[1], z=v[2]), angular=V3(x=v[3], y=v[4], z=v[5]))))
        elif kind == "WrenchStamped":
            msgs.append(T[geo + "WrenchStamped"](header=head, wrench=T[geo + "Wrench"](
                force=V3(x=v[0], y=v[1], z=v[2]), torque=V3(x=v[3], y=v[4], z=v[5]))))
        else:
            Dim = T["std_msgs/msg/MultiArrayDimension"]
            layout = T["std_msgs/msg/MultiArrayLayout"](dim=[Dim(label="joints", size=7, stride=7)],
                                                        data_offset=0)
            msgs.append(T["std_msgs/msg/Float64MultiArray"](layout=layout, data=v.copy()))
    return msgs, vals


PACKAGE = {"PoseStamped": "geometry_msgs", "TwistStamped": "geometry_msgs", "WrenchStamped": "geometry_msgs",
           "Float64MultiArray": "std_msgs"}
FIELDS = {"PoseStamped": ["pose.position", "pose.orientation", "pose"],
          "TwistStamped": ["twist.linear", "twist.angular", "twist"],
          "WrenchStamped": ["wrench.force", "wrench.torque"], "Float64MultiArray": ["data"]}


def _write(tmp_path: Path, container: str, kind: str, n: int, rng) -> tuple[Path, np.ndarray]:
    from rosbags.typesys import Stores, get_typestore

    msgtype = f"{PACKAGE[kind]}/msg/{kind}"
    ts = get_typestore(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE)
    msgs, vals = _messages(ts, kind, n, rng)
    if container == "ros1":
        from rosbags.rosbag1 import Writer

        path = tmp_path / "x.bag"
        with Writer(path) as w:
            conn = w.add_connection("/x", msgtype, typestore=ts)
            for i, m in enumerate(msgs):
                w.write(conn, 10**9 + i * 10**6, ts.serialize_ros1(m, msgtype))
        return path, vals
    from mcap.writer import Writer

    path = tmp_path / "x.mcap"
    msgdef, _ = ts.generate_msgdef(msgtype, ros_version=2)
    with open(path, "wb") as f:
        w = Writer(f)
        w.start(profile="ros2", library="tests")
        sid = w.register_schema(msgtype, "ros2msg", msgdef.encode())
        cid = w.register_channel("/x", "cdr", sid)
        for i, m in enumerate(msgs):
            t = 10**9 + i * 10**6
            w.add_message(cid, t, bytes(ts.serialize_cdr(m, msgtype)), t)
        w.finish()
    return path, vals


@pytest.mark.parametrize("container", ["ros1", "mcap-cdr"])
@pytest.mark.parametrize("kind", sorted(FIELDS))
def test_other_types_equal_the_message_path(tmp_path, container, kind, gathered, monkeypatch):
    path, vals = _write(tmp_path, container, kind, 1500, np.random.default_rng(len(kind)))
    reader_cls = BagReader if container == "ros1" else McapReader
    options = DataOptions.model_validate({"state": {"topic": "/x", "field": FIELDS[kind][0]}})
    sel = [StreamOptions.model_validate({"topic": "/x", "field": f}) for f in FIELDS[kind]]
    fast = reader_cls(path, options).streams(sel)
    assert gathered == ["/x"]
    monkeypatch.setattr(layouts, "WALKS", {})
    slow = reader_cls(path, options).streams(sel)
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a.values, b.values)
        np.testing.assert_array_equal(a.t_ns, b.t_ns)
        assert a.names == b.names and a.meta == b.meta
    width = fast[0].values.shape[1]
    np.testing.assert_array_equal(fast[0].values, vals[:, :width])  # the numbers written
    np.testing.assert_array_equal(fast[0].t_ns, 100 * 10**9 + np.arange(1500) * (10**9 + 7)
                                  if kind != "Float64MultiArray" else 10**9 + np.arange(1500) * 10**6)


@pytest.mark.parametrize("container", ["ros1", "mcap-cdr"])
def test_a_length_change_falls_back_to_the_message_path_and_its_error(tmp_path, container, gathered):
    from rosbags.typesys import Stores, get_typestore

    from ccl_cli.errors import InputError

    msgtype = "std_msgs/msg/Float64MultiArray"
    ts = get_typestore(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE)
    msgs, _ = _messages(ts, "Float64MultiArray", 300, np.random.default_rng(0))
    msgs[200].data = msgs[200].data[:6]  # one message one number short
    path = tmp_path / ("x.bag" if container == "ros1" else "x.mcap")
    if container == "ros1":
        from rosbags.rosbag1 import Writer

        with Writer(path) as w:
            conn = w.add_connection("/x", msgtype, typestore=ts)
            for i, m in enumerate(msgs):
                w.write(conn, 10**9 + i, ts.serialize_ros1(m, msgtype))
    else:
        from mcap.writer import Writer

        with open(path, "wb") as f:
            w = Writer(f)
            w.start(profile="ros2", library="tests")
            cid = w.register_channel("/x", "cdr", w.register_schema(
                msgtype, "ros2msg", ts.generate_msgdef(msgtype, ros_version=2)[0].encode()))
            for i, m in enumerate(msgs):
                w.add_message(cid, 10**9 + i, bytes(ts.serialize_cdr(m, msgtype)), 10**9 + i)
            w.finish()
    reader_cls = BagReader if container == "ros1" else McapReader
    options = DataOptions.model_validate({"state": {"topic": "/x"}})
    with pytest.raises(InputError, match="changes length"):
        reader_cls(path, options).streams([StreamOptions.model_validate({"topic": "/x"})])
    assert gathered == []


def test_progress_hook_sees_the_chunks_of_a_long_read(tmp_path):
    from contextlib import contextmanager

    from ccl_cli import progress

    seen: dict[str, float] = {}

    @contextmanager
    def hook(label, total):
        seen["total"], seen["done"] = total, 0.0

        def advance(units):
            seen["done"] += units

        yield advance

    path = WRITERS["ros1"](tmp_path, joint_recording(n=5000))
    previous = progress.install(hook)
    try:
        load_demonstrations({"files": [str(path)], "state": {"topic": "/joint_states"}})
    finally:
        progress.install(previous)
    assert seen["total"] > 5000 * 8 * 14 and seen["done"] == seen["total"]  # every chunk's bytes
    assert progress.terminal_hook(quiet=True) is None


def test_terminal_bar_stands_aside_while_another_display_is_live():
    from ccl_cli import progress

    progress.live(+1)  # e.g. the stage bar of ccl run
    try:
        with progress._rich_bar("reading", 100.0) as advance:
            assert advance is progress._ignore
    finally:
        progress.live(-1)


# -- topics interleaved in the chunks: records not back to back, gathered one by one ----------
def _write_interleaved(tmp_path: Path, container: str, n: int) -> tuple[Path, dict[str, np.ndarray]]:
    """PoseStamped on /x and WrenchStamped on /y, one message of each in turn, in chunks of
    about 16 kB; returns the numbers written per topic."""
    from rosbags.typesys import Stores, get_typestore

    ts = get_typestore(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE)
    rng = np.random.default_rng(11)
    topics = {"/x": "PoseStamped", "/y": "WrenchStamped"}
    written = {t: _messages(ts, kind, n, rng) for t, kind in topics.items()}
    types = {t: f"geometry_msgs/msg/{kind}" for t, kind in topics.items()}
    if container == "ros1":
        from rosbags.rosbag1 import Writer

        path = tmp_path / "two.bag"
        w = Writer(path)
        w.chunk_threshold = 1 << 14
        with w:
            conns = {t: w.add_connection(t, types[t], typestore=ts) for t in topics}
            for i in range(n):
                for k, t in enumerate(topics):
                    data = ts.serialize_ros1(written[t][0][i], types[t])
                    w.write(conns[t], 10**9 + 2 * i * 10**6 + k, data)
    else:
        from mcap.writer import Writer

        path = tmp_path / "two.mcap"
        with open(path, "wb") as f:
            w = Writer(f, chunk_size=1 << 14)
            w.start(profile="ros2", library="tests")
            schemas = {t: w.register_schema(types[t], "ros2msg",
                                            ts.generate_msgdef(types[t], ros_version=2)[0].encode())
                       for t in topics}
            cids = {t: w.register_channel(t, "cdr", schemas[t]) for t in topics}
            for i in range(n):
                for k, t in enumerate(topics):
                    stamp = 10**9 + 2 * i * 10**6 + k
                    w.add_message(cids[t], stamp, bytes(ts.serialize_cdr(written[t][0][i], types[t])), stamp)
            w.finish()
    return path, {t: vals for t, (_, vals) in written.items()}


@pytest.mark.parametrize("container", ["ros1", "mcap-cdr"])
def test_interleaved_topics_equal_the_message_path(tmp_path, container, gathered, monkeypatch):
    path, vals = _write_interleaved(tmp_path, container, 2500)
    reader_cls = BagReader if container == "ros1" else McapReader
    options = DataOptions.model_validate({"state": {"topic": "/x", "field": "pose.position"}})
    sel = [StreamOptions.model_validate({"topic": t, "field": f}) for t, f in
           (("/x", "pose.position"), ("/y", "wrench.torque"), ("/x", "pose.orientation"))]
    fast = reader_cls(path, options).streams(sel)
    assert sorted(gathered) == ["/x", "/y"]  # both topics on the NumPy path
    np.testing.assert_array_equal(fast[0].values, vals["/x"][:, :3])
    np.testing.assert_array_equal(fast[1].values, vals["/y"][:, 3:6])
    np.testing.assert_array_equal(fast[2].values, vals["/x"][:, 3:7])
    monkeypatch.setattr(layouts, "WALKS", {})
    slow = reader_cls(path, options).streams(sel)
    for a, b in zip(fast, slow, strict=True):
        np.testing.assert_array_equal(a.values, b.values)
        np.testing.assert_array_equal(a.t_ns, b.t_ns)
        assert a.meta == b.meta


def test_bag_index_equals_rosbags_index(tmp_path):
    from rosbags.rosbag1 import Reader

    from ccl_cli.io.formats.bag1 import read_index

    path, _ = _write_interleaved(tmp_path, "ros1", 1500)
    index = read_index(path)
    with Reader(path) as r:
        chunk_pos = sorted({e.chunk_pos for entries in r.indexes.values() for e in entries})
        assert len(index.chunks) == len(chunk_pos) > 10
        for conn in r.connections:
            theirs = np.array([(e.time, chunk_pos.index(e.chunk_pos), e.offset) for e in r.indexes[conn.id]])
            np.testing.assert_array_equal(index.entries[conn.id], theirs)


def test_a_bag_index_disagreeing_with_its_chunk_info_is_refused_and_read_by_rosbags(tmp_path, gathered):
    from ccl_cli.errors import InputError
    from ccl_cli.io.formats.bag1 import read_index

    rec = joint_recording(n=3000, seed=2)
    path = WRITERS["ros1"](tmp_path, rec)
    raw = bytearray(path.read_bytes())
    # the index ends with the last chunk's info record, whose data ends with (conn, count)
    conn, count = np.frombuffer(bytes(raw[-8:]), dtype="<u4").tolist()
    assert conn == 0 and 0 < count <= 3000
    raw[-4:] = (count + 1).to_bytes(4, "little")
    path.write_bytes(bytes(raw))
    with pytest.raises(InputError, match="disagrees with its chunk info"):
        read_index(path)
    options = DataOptions.model_validate({"state": {"topic": "/joint_states", "field": "position"}})
    (stream,) = BagReader(path, options).streams([options.state])
    assert gathered == []  # rosbags' reader, which uses the index data records
    np.testing.assert_array_equal(stream.values, rec.position)


def test_in_order_is_lexicographic_order():
    from ccl_cli.io.formats.bag1 import in_order

    rng = np.random.default_rng(4)
    for _ in range(500):
        keys = rng.integers(0, 3, size=(rng.integers(0, 7), 3))
        assert in_order(keys) == (sorted(map(tuple, keys)) == list(map(tuple, keys)))


@pytest.mark.parametrize("container", ["ros1", "mcap-cdr"])
def test_messages_written_out_of_log_time_order_equal_the_message_path(tmp_path, container, gathered,
                                                                       monkeypatch):
    """Log times that go back now and then, and repeat: the index is not in file order, so
    the entries are sorted (ROS 1: log time, chunk, offset; MCAP: offsets per chunk)."""
    from rosbags.typesys import Stores, get_typestore

    n, kind, msgtype = 3000, "PoseStamped", "geometry_msgs/msg/PoseStamped"
    ts = get_typestore(Stores.ROS1_NOETIC if container == "ros1" else Stores.ROS2_HUMBLE)
    msgs, vals = _messages(ts, kind, n, np.random.default_rng(8))
    log = 10**9 + np.arange(n) * 10**6
    log[10::10], log[11::10] = log[11::10].copy(), log[10::10].copy()  # pairs swapped
    log[25::50] = log[24::50]  # and ties
    log[-2:] = log[-1], log[-2]  # the last message written is not the last in time
    if container == "ros1":
        from rosbags.rosbag1 import Writer

        path = tmp_path / "x.bag"
        w = Writer(path)
        w.chunk_threshold = 1 << 14
        with w:
            conn = w.add_connection("/x", msgtype, typestore=ts)
            for t, m in zip(log.tolist(), msgs, strict=True):
                w.write(conn, t, ts.serialize_ros1(m, msgtype))
    else:
        from mcap.writer import Writer

        path = tmp_path / "x.mcap"
        with open(path, "wb") as f:
            w = Writer(f, chunk_size=1 << 14)
            w.start(profile="ros2", library="tests")
            cid = w.register_channel("/x", "cdr", w.register_schema(
                msgtype, "ros2msg", ts.generate_msgdef(msgtype, ros_version=2)[0].encode()))
            for t, m in zip(log.tolist(), msgs, strict=True):
                w.add_message(cid, t, bytes(ts.serialize_cdr(m, msgtype)), t)
            w.finish()
    reader_cls = BagReader if container == "ros1" else McapReader
    options = DataOptions.model_validate({"state": {"topic": "/x", "field": "pose.position"}})
    sel = [StreamOptions.model_validate({"topic": "/x", "field": "pose.position", "stamp": "log"})]
    (fast,) = reader_cls(path, options).streams(sel)
    assert gathered == ["/x"]
    order = np.argsort(log, kind="stable")  # log-time order, ties in the order written
    np.testing.assert_array_equal(fast.t_ns, log[order])
    np.testing.assert_array_equal(fast.values, vals[order, :3])
    listing = reader_cls(path, options).listing()  # from the index (ROS 1) or the summary
    assert (listing["start_ns"], listing["end_ns"]) == (log.min(), log.max())
    monkeypatch.setattr(layouts, "WALKS", {})
    (slow,) = reader_cls(path, options).streams(sel)
    np.testing.assert_array_equal(fast.values, slow.values)
    np.testing.assert_array_equal(fast.t_ns, slow.t_ns)
