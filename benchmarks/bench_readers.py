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

Run:  python benchmarks/bench_readers.py [--n 1000000] [--containers ros1,mcap-ros2,...]
"""

from __future__ import annotations

import argparse
import json
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
if mode == "mem":
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


def run(mode: str, container: str, path: Path) -> dict:
    code = CHILD.format(tests=str(HERE.parent / "tests"))
    out = subprocess.run([sys.executable, "-c", code, mode, container, str(path)], check=True,
                         capture_output=True, text=True)
    return json.loads(out.stdout.strip().splitlines()[-1])


def main() -> int:
    from writers import WRITERS, joint_recording

    ap = argparse.ArgumentParser()
    ap.add_argument("--n", type=int, default=1_000_000)
    ap.add_argument("--containers", default=",".join(sorted(WRITERS)))
    args = ap.parse_args()
    rec = joint_recording(n=args.n, shuffle=False)
    for container in args.containers.split(","):
        with tempfile.TemporaryDirectory() as tmp:
            t = time.perf_counter()
            path = WRITERS[container](Path(tmp), rec)
            write_s = time.perf_counter() - t
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
