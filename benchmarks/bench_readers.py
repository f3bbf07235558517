"""Reader throughput and memory. One JSON object per line:
{"container", "N", "bare_msgs_per_s", "ccl_msgs_per_s", "overhead", "peak_mb", "arrays_mb", "peak_ratio"}.

For each container a file of N JointState messages (7 joints) is written with the
third-party writers, then read (a) by bare library iteration that only deserialises
each message and (b) by ccl's loader (state = positions, action = velocities, both
from the same topic), each in a fresh process; (c) the loader once more under
tracemalloc for the peak of memory allocated while reading (NumPy's buffers included),
compared with the size of the arrays returned.

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
from ccl_cli.io import load_demonstrations
import rosbags.highlevel, mcap.reader, mcap_ros2.decoder, mcap_ros1.decoder
if mode == "mem":
    import tracemalloc
    tracemalloc.start()
t0 = time.perf_counter()
n = 0
if mode == "bare":
    if container.startswith("ros"):
        from rosbags.highlevel import AnyReader
        from rosbags.typesys import Stores, get_typestore
        with AnyReader([path], default_typestore=get_typestore(Stores.ROS2_HUMBLE)) as r:
            for conn, t, raw in r.messages():
                r.deserialize(raw, conn.msgtype); n += 1
    elif container == "mcap-json":
        from mcap.reader import make_reader
        with open(path, "rb") as f:
            for _, _, m in make_reader(f).iter_messages():
                json.loads(m.data); n += 1
    else:
        from mcap.reader import make_reader
        from mcap_ros1.decoder import DecoderFactory as D1
        from mcap_ros2.decoder import DecoderFactory as D2
        with open(path, "rb") as f:
            for _ in make_reader(f, decoder_factories=[D2(), D1()]).iter_decoded_messages():
                n += 1
else:
    cfg = {{"files": [str(path)],
           "state": {{"topic": "/joint_states", "field": "position", "joints": JOINTS}},
           "action": {{"topic": "/joint_states", "field": "velocity", "joints": JOINTS}}}}
    d = load_demonstrations(cfg)
    n = d.n_samples
    arrays = d.X.nbytes + d.U.nbytes + d.t.nbytes + d.demo.nbytes
seconds = time.perf_counter() - t0
peak = tracemalloc.get_traced_memory()[1] if mode == "mem" else 0
print(json.dumps({{"n": n, "seconds": seconds, "peak": peak, "arrays": arrays if mode != "bare" else 0}}))
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
            bare = run("bare", container, path)
            ours = run("ccl", container, path)
            mem = run("mem", container, path)
            print(json.dumps({
                "container": container, "N": args.n, "write_seconds": round(write_s, 2),
                "bare_seconds": round(bare["seconds"], 2), "ccl_seconds": round(ours["seconds"], 2),
                "bare_msgs_per_s": round(bare["n"] / bare["seconds"]),
                "ccl_msgs_per_s": round(ours["n"] / ours["seconds"]),
                "overhead": round(ours["seconds"] / bare["seconds"] - 1.0, 3),
                "peak_mb": round(mem["peak"] / 2**20, 1), "arrays_mb": round(mem["arrays"] / 2**20, 1),
                "peak_ratio": round(mem["peak"] / max(mem["arrays"], 1), 2),
            }), flush=True)
    return 0


if __name__ == "__main__":
    sys.exit(main())
