"""Sensor faults through the readers and the command line (issue 17 item 4): a tracker export
with hemisphere flips, spikes and stamp faults is repaired by default, every fault is reported
with its count and time ranges, and ``data.faults`` keeps them."""

from __future__ import annotations

import csv
import json

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.metrics import subspace_angle

T0_NS = 1_700_000_000_000_000_000


def export(path, data, t=None) -> None:
    """A raw rosbag→CSV export of a tracker, as Trakstar users have them: rosbagTimestamp
    (int ns), x, y, z."""
    t = data.t if t is None else t
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["rosbagTimestamp", "x", "y", "z"])
        for stamp, x in zip(T0_NS + np.round(t * 1e9).astype(np.int64), data.X, strict=True):
            w.writerow([int(stamp), *(f"{v:.7f}" for v in x)])


def learn(capsys, tmp_path, csv_path, faults: str = "") -> tuple[int, dict, str]:
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data:\n  state: {columns: [x, y, z]}\n" + (f"  faults: {faults}\n" if faults else "")
                   + "learn-a: {method: nhat}\n")
    out = tmp_path / ("out" + str(abs(hash(faults))))
    code = main(["learn-a", str(csv_path), "-c", str(cfg), "-o", str(out), "--json"])
    captured = capsys.readouterr()
    summary = json.loads(captured.out) if captured.out.strip() else {}
    metrics = json.loads((out / "metrics.json").read_text()) if code == 0 else {}
    return code, {"summary": summary, "metrics": metrics}, captured.err


def normal_angle(metrics: dict, truth) -> float:
    n = np.asarray(metrics["learn-a"]["constraint"]["plane_normal"])
    return subspace_angle(n[None], truth.truth_per_sample("A")[0])


@pytest.mark.parametrize("seed", [0, 3])
def test_flips_are_mirrored_back_reported_and_the_plane_is_right(capsys, tmp_path, seed):
    data = sim.tracker_flips(seed=seed)
    injected = next(f for f in data.metadata["faults"] if f["kind"] == "hemisphere_flip")
    path = tmp_path / "trakstar.csv"
    export(path, data)
    code, out, err = learn(capsys, tmp_path, path)
    assert code == 0, err
    flips = [w for w in out["summary"]["warnings"] if w["code"] == "hemisphere_flips"]
    assert len(flips) == 1 and f"{injected['count']} hemisphere flip(s)" in flips[0]["message"]
    assert "mirrored" in flips[0]["message"] and "flips: keep" in flips[0]["message"]
    assert out["metrics"]["learn-a"]["n_constraints"] == 1
    assert normal_angle(out["metrics"], data) < 5.0  # the bar: within 5° after repair
    # kept as recorded (data.faults.flips: keep): reported, and the normal is pulled off
    code, kept, err = learn(capsys, tmp_path, path, "{flips: keep}")
    assert code == 0, err
    assert any("kept as recorded" in w["message"] for w in kept["summary"]["warnings"])
    assert normal_angle(kept["metrics"], data) > normal_angle(out["metrics"], data)


def test_stamp_faults_and_spikes_are_repaired_and_reported(capsys, tmp_path):
    data = sim.tracker_plane(duration=40.0, seed=2)
    t = data.t.copy()
    t[700] = t[699]  # a repeated stamp
    X = data.X.copy()
    X[1200] += [0.05, -0.04, 0.03]  # a 7-cm spike
    path = tmp_path / "faulty.csv"
    export(path, type(data)(X=X, U=data.U, t=t), t)
    code, out, err = learn(capsys, tmp_path, path)
    assert code == 0, err
    codes = {w["code"]: w["message"] for w in out["summary"]["warnings"]}
    assert "restamped" in codes["stamp_faults"]
    assert "1 repeated or misplaced stamp(s)" in codes["stamp_faults"]
    assert "1 spike(s)" in codes["spikes"] and "dropped" in codes["spikes"]
    assert normal_angle(out["metrics"], data) < 1.0
    # stamps kept as recorded: the repeated stamp is refused, as before
    code, _, err = learn(capsys, tmp_path, path, "{stamps: keep}")
    assert code == 2 and "not strictly increasing" in err


def test_clean_recordings_report_no_fault(capsys, tmp_path):
    data = sim.tracker_sphere(duration=30.0, seed=5)
    path = tmp_path / "bowl.csv"
    export(path, data)
    code, out, err = learn(capsys, tmp_path, path)
    assert code == 0, err
    found = {w["code"] for w in out["summary"]["warnings"]}
    assert not found & {"hemisphere_flips", "spikes", "stamp_faults"}
