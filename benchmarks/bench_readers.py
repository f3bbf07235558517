"""Reader throughput and memory. One JSON object per line:
{"container", "N", "library_seconds", "ccl_extra_seconds", "overhead", "ccl_end_to_end_seconds",
 "peak_mb", "arrays_mb", "peak_ratio", ...}.

For each container a file of N JointState messages (7 joints) is written with the
third-party writers. "overhead" is measured in one process, interleaved so that the
machine's drift hits both sides alike: the library iterates and deserialises a chunk of
20,000 messages (timed: library_seconds), then ccl's collector takes the same decoded
messages (timed: ccl_extra_seconds, plus building the arrays at the end); overhead =
ccl_extra / library. ccl_end_to_end_seconds is the whole loader (state = positions,
action = velocities from the same topic) in a fresh process; peak memory is measured
under tracemalloc (NumPy's buffers included) against the size of the arrays returned.

With ``--floor`` (containers ros1, ros1-bz2, mcap-ros1, mcap-ros2) the numpy decode floor
is measured next to ccl, in fresh processes run back to back: ``floor_seconds`` reads and
decompresses every chunk (the libraries' codecs) and gathers stamps, positions and
velocities of the fixed-layout records at places computed beforehand (one fancy index
per chunk, no checks); ``reader_seconds`` is ccl's reader (both streams),
``loader_seconds`` the whole loader (faults, alignment, demonstrations) and
``convert_seconds`` the ``ccl convert`` command, each with its ratio to the floor (the
smaller of two floor runs, one before and one after). ``*_cpu_seconds`` and ``*_cpu_ratio``
are the same in CPU seconds (the floor's in its process, convert's as the child's user +
system time, start-up included): steadier than wall time on a loaded machine.
``peak_ratio`` is the loader's peak traced memory over the arrays it returns. With
``--before DIR`` (a source tree of ccl_cli, e.g. ``git archive main | tar -x -C DIR``) the
loader, convert and peak memory of that tree are measured in the same run, interleaved,
under ``before_*`` keys. With ``--compiled`` both trees are byte-compiled first: this VM sets
PYTHONDONTWRITEBYTECODE and the work trees hold no ``__pycache__``, so by default every
``ccl convert`` start compiles ccl_cli's sources (0.07–0.1 s), which an installed package does not.

Run:  python benchmarks/bench_readers.py [--n 1000000] [--containers ros1,mcap-ros2,...] [--floor]
      [--path FILE] [--before DIR] [--compiled]
"""

from __future__ import annotations

import argparse
import json
import os
import resource
import subprocess
import sys
import tempfile
import time
from pathlib import Path

HERE = Path(__file__).resolve().parent
sys.path.insert(0, str(HERE.parent / "tests"))

CHILD = r"""
import json, sys, time
from pathlib import Path
sys.path.insert(0, {tests!r})
mode, container, path = sys.argv[1], sys.argv[2], Path(sys.argv[3])
from writers import JOINTS
from ccl_cli.io import StreamOptions, load_demonstrations
from ccl_cli.io.messages import read_topics, finish_topics
import rosbags.highlevel, mcap.reader, mcap_ros2.decoder, mcap_ros1.decoder
cfg = {{"files": [str(path)],
       "state": {{"topic": "/joint_states", "field": "position", "joints": JOINTS}},
       "action": {{"topic": "/joint_states", "field": "velocity", "joints": JOINTS}}}}
out = {{}}
if mode == "floor":
    import numpy as np
    from ccl_cli.io.layouts import gather_rows, layout_of
    if container.startswith("ros1"):
        from ccl_cli.io.formats.bag1 import read_index
        from rosbags.rosbag1.reader import decompressors
        index = read_index(path)
        (entries,) = index.entries.values()
        plan = []  # per chunk: where its data is, its codec, the record starts of its messages
        for k, chunk in enumerate(index.chunks):
            plan.append((chunk.data_pos, chunk.data_len, decompressors[chunk.compression],
                         np.sort(entries[entries[:, 1] == k, 2])))
        with open(path, "rb") as f:
            f.seek(plan[0][0]); buf = np.frombuffer(plan[0][2](f.read(plan[0][1])), np.uint8)
        hlen = int(buf[plan[0][3][0]:plan[0][3][0] + 4].view("<u4")[0])
        skip = 8 + hlen
        size = int(buf[plan[0][3][0] + 4 + hlen:plan[0][3][0] + 8 + hlen].view("<u4")[0])
        first = bytes(buf[plan[0][3][0] + skip:plan[0][3][0] + skip + size]); cdr = False
    else:
        from mcap.reader import make_reader
        from mcap.records import Chunk
        from mcap.data_stream import ReadDataStream
        from mcap.stream_reader import get_chunk_data_stream
        from ccl_cli.io.formats.mcap import McapReader, MESSAGE_PREFIX
        from ccl_cli.io.options import DataOptions
        r = McapReader(path, DataOptions())
        plan = []
        with open(path, "rb") as f:
            summary = make_reader(f).get_summary()
            for ci in sorted(summary.chunk_indexes, key=lambda c: c.chunk_start_offset):
                (off,) = ci.message_index_offsets.values()
                (cid,) = ci.message_index_offsets
                starts = r._message_index(f, off, cid)[:, 1].astype(np.int64)
                plan.append((ci.chunk_start_offset + 9, None, None, np.sort(starts)))
            buf = r._chunk(f, summary.chunk_indexes[0])
        skip = MESSAGE_PREFIX
        size = int(buf[plan[0][3][0] + 1:plan[0][3][0] + 9].view("<u8")[0]) - (MESSAGE_PREFIX - 9)
        first = bytes(buf[plan[0][3][0] + skip:plan[0][3][0] + skip + size]); cdr = first[:2] == b"\x00\x01"
    layout = layout_of("JointState", first, cdr)
    (_, p_at, _), (_, v_at, _) = layout.runs[:2]
    s_at = layout.stamp[0]
    total = sum(len(p[3]) for p in plan)
    t, cpu = time.perf_counter(), time.process_time()
    pos, vel, stamp = np.empty((total, 7)), np.empty((total, 7)), np.empty(total, np.int64)
    n = 0
    with open(path, "rb") as f:
        for pos_, length, decompress, starts in plan:
            f.seek(pos_)
            if container.startswith("ros1"):
                buf = np.frombuffer(decompress(f.read(length)), np.uint8)
            else:
                stream, size_ = get_chunk_data_stream(Chunk.read(ReadDataStream(f)))
                buf = np.frombuffer(stream.read(size_), np.uint8)
            rows = gather_rows(buf, starts + skip, layout.size)
            m = len(starts)
            pos[n:n + m] = rows[:, p_at:p_at + 56].copy().view("<f8")
            vel[n:n + m] = rows[:, v_at:v_at + 56].copy().view("<f8")
            st = rows[:, s_at:s_at + 8].copy().view("<u4").astype(np.int64)
            stamp[n:n + m] = st[:, 0] * 1_000_000_000 + st[:, 1]
            n += m
    out = {{"seconds": time.perf_counter() - t, "cpu": time.process_time() - cpu, "n": n}}
elif mode == "reader":
    from ccl_cli.io.formats.bag import BagReader
    from ccl_cli.io.formats.mcap import McapReader
    from ccl_cli.io.options import DataOptions
    options = DataOptions.model_validate({{k: v for k, v in cfg.items() if k != "files"}})
    cls = BagReader if container.startswith("ros") else McapReader
    t = time.perf_counter()
    streams = cls(path, options).streams([options.state, options.action])
    out = {{"seconds": time.perf_counter() - t, "n": len(streams[0].t_ns)}}
elif mode == "mem":
    import tracemalloc
    tracemalloc.start()
    d = load_demonstrations(cfg)
    out = {{"peak": tracemalloc.get_traced_memory()[1],
           "arrays": d.X.nbytes + d.U.nbytes + d.t.nbytes + d.demo.nbytes}}
elif mode == "e2e":
    t0 = time.perf_counter()
    d = load_demonstrations(cfg)
    out = {{"seconds": time.perf_counter() - t0, "n": d.n_samples}}
else:  # interleaved: library decode of a chunk, then ccl's collection of the same chunk
    specs = [StreamOptions.model_validate(cfg["state"]), StreamOptions.model_validate(cfg["action"])]
    collectors, slots = read_topics(specs, {{"/joint_states": "sensor_msgs/msg/JointState"}}, str(path))
    col = collectors["/joint_states"]
    lib = ours = 0.0
    n = 0
    CHUNK = 20000
    def chunks():
        if container.startswith("ros"):
            from rosbags.highlevel import AnyReader
            from rosbags.typesys import Stores, get_typestore
            with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
                it = r.messages()
                while True:
                    t = time.perf_counter(); batch = []
                    for conn, log, raw in it:
                        batch.append((r.deserialize(raw, conn.msgtype), log))
                        if len(batch) == CHUNK: break
                    yield time.perf_counter() - t, batch
                    if len(batch) < CHUNK: return
        else:
            from mcap.reader import make_reader
            from mcap_ros1.decoder import DecoderFactory as D1
            from mcap_ros2.decoder import DecoderFactory as D2
            with open(path, "rb") as f:
                if container == "mcap-json":
                    it = ((json.loads(m.data), m.log_time) for _, _, m in make_reader(f).iter_messages())
                else:
                    it = ((dec, m.log_time) for _, _, m, dec in
                          make_reader(f, decoder_factories=[D2(), D1()]).iter_decoded_messages())
                while True:
                    t = time.perf_counter(); batch = []
                    for item in it:
                        batch.append(item)
                        if len(batch) == CHUNK: break
                    yield time.perf_counter() - t, batch
                    if len(batch) < CHUNK: return
    for seconds, batch in chunks():
        lib += seconds
        t = time.perf_counter()
        for msg, log in batch:
            col.add(msg, log)
        ours += time.perf_counter() - t
        n += len(batch)
    t = time.perf_counter()
    finish_topics(collectors, slots)
    ours += time.perf_counter() - t
    out = {{"n": n, "library_seconds": lib, "ccl_seconds": ours}}
print(json.dumps(out))
"""


CCL = "import sys; from ccl_cli.cli import entry; sys.argv[0] = 'ccl'; sys.exit(entry())"


def _child(src: Path | None) -> dict:
    """subprocess.run arguments that import ccl_cli from the source tree ``src`` (None: this
    one): its folder first on the path, and as the working folder (``-c`` puts that first)."""
    return {} if src is None else {"env": {**os.environ, "PYTHONPATH": str(src)}, "cwd": str(src)}


def convert_seconds(path: Path, tmp: str, src: Path | None = None) -> tuple[float, float]:
    """Wall and CPU (user + system) seconds of ``ccl convert`` (a fresh process) on ``path``."""
    from writers import JOINTS

    cfg = Path(tmp) / "convert.yaml"
    cfg.write_text(json.dumps({"data": {
        "state": {"topic": "/joint_states", "field": "position", "joints": JOINTS},
        "action": {"topic": "/joint_states", "field": "velocity", "joints": JOINTS}}}))
    out = str(Path(tmp) / "out.h5")
    before = resource.getrusage(resource.RUSAGE_CHILDREN)
    t = time.perf_counter()
    subprocess.run([sys.executable, "-c", CCL, "convert", str(path), "-c", str(cfg), "-q", "--force",
                    "-o", out], check=True, capture_output=True, **_child(src))
    wall = time.perf_counter() - t
    after = resource.getrusage(resource.RUSAGE_CHILDREN)
    return wall, (after.ru_utime - before.ru_utime) + (after.ru_stime - before.ru_stime)


def floors(container: str, path: Path, tmp: str, n: int, src: Path | None = None,
           compiled: bool = False) -> dict:
    """Reader, loader, ``ccl convert`` and the loader's peak memory against the numpy decode
    floor (run back to back; with ``src``, that tree's loader, convert and peak interleaved)."""
    first = run("floor", container, path)
    reader = run("reader", container, path)["seconds"]
    out: dict = {}
    for label, tree in (("", None), ("before_", src)) if src is not None else (("", None),):
        loader = run("e2e", container, path, tree)["seconds"]
        wall, cpu = convert_seconds(path, tmp, tree)
        mem = run("mem", container, path, tree)
        out[label] = (loader, wall, cpu, mem["peak"] / max(mem["arrays"], 1))
    last = run("floor", container, path)
    floor, floor_cpu = min(first["seconds"], last["seconds"]), min(first["cpu"], last["cpu"])
    row = {"container": container, "N": n, "compiled": compiled, "floor_seconds": round(floor, 3),
           "floor_cpu_seconds": round(floor_cpu, 3),
           "reader_seconds": round(reader, 3), "reader_ratio": round(reader / floor, 2)}
    for label, (loader, wall, cpu, peak) in out.items():
        row.update({f"{label}loader_seconds": round(loader, 3),
                    f"{label}loader_ratio": round(loader / floor, 2),
                    f"{label}convert_seconds": round(wall, 3),
                    f"{label}convert_ratio": round(wall / floor, 2),
                    f"{label}convert_cpu_seconds": round(cpu, 3),
                    f"{label}convert_cpu_ratio": round(cpu / floor_cpu, 2),
                    f"{label}peak_ratio": round(peak, 2)})
    return row


def run(mode: str, container: str, path: Path, src: Path | None = None) -> dict:
    code = CHILD.format(tests=str(HERE.parent / "tests"))
    out = subprocess.run([sys.executable, "-c", code, mode, container, str(path)], check=True,
                         capture_output=True, text=True, **_child(src))
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    from writers import WRITERS, joint_recording

    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--containers", default=",".join(sorted(WRITERS)))
    ap.add_argument("--floor", action="store_true", help="reader, loader and convert against the floor")
    ap.add_argument("--path", type=Path, help="an existing file of N JointState (one container)")
    ap.add_argument("--before", type=Path, help="a ccl_cli source tree measured beside this one (--floor)")
    ap.add_argument("--compiled", action="store_true",
                    help="byte-compile the measured trees first, as an installed package is (with "
                         "PYTHONDONTWRITEBYTECODE set and no __pycache__, every start compiles ccl_cli)")
    args = ap.parse_args()
    if args.compiled:
        for tree in (HERE.parent, args.before):
            if tree is not None:
                subprocess.run([sys.executable, "-m", "compileall", "-q", str(tree / "ccl_cli")], check=True)
    rec = None if args.path else joint_recording(n=args.n, shuffle=False)
    for container in args.containers.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            path = args.path or WRITERS[container](Path(tmp), rec)
            write_s = time.perf_counter() - t
            if args.floor:
                row = floors(container, path, tmp, args.n, args.before, args.compiled)
                print(json.dumps(row), flush=True)
                continue
            split = run("split", container, path)
            e2e = run("e2e", container, path)
            mem = run("mem", container, path)
            print(json.dumps({
                "container": container, "N": args.n, "write_seconds": round(write_s, 2),
                "library_seconds": round(split["library_seconds"], 2),
                "ccl_extra_seconds": round(split["ccl_seconds"], 2),
                "overhead": round(split["ccl_seconds"] / split["library_seconds"], 3),
                "library_msgs_per_s": round(split["n"] / split["library_seconds"]),
                "ccl_end_to_end_seconds": round(e2e["seconds"], 2),
                "ccl_end_to_end_msgs_per_s": round(e2e["n"] / e2e["seconds"]),
                "peak_mb": round(mem["peak"] / 2**20, 1), "arrays_mb": round(mem["arrays"] / 2**20, 1),
                "peak_ratio": round(mem["peak"] / max(mem["arrays"], 1), 2),
            }), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
