"""Sensor faults in recordings read as arrays (issue 17 item 4): a tracker recording with
hemisphere flips, spikes and stamp faults written as canonical HDF5, as a foreign HDF5 layout
(h5py) or as a .mat file (scipy) is repaired as a CSV export is, every fault reported; stored
actions next to a repair are dropped, mirrored with a flip when they follow the positions; clean
simulations report nothing."""

from __future__ import annotations

import json
from dataclasses import replace

import h5py
import numpy as np
import pytest
import scipy.io

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import load_demonstrations
from ccl_cli.io.canonical import write_demonstrations
from ccl_cli.io.derivative import derive_actions
from ccl_cli.io.options import FaultOptions
from ccl_cli.io.stored_faults import repair_recording
from ccl_cli.learn.constraint import StateIndependentConstraint
from ccl_cli.metrics import subspace_angle


def flipped(seed: int):
    """A tracker recording with 3 hemisphere flips, its actions derived from the flipped
    positions (as a tool that knows nothing of flips writes them), without ground truth."""
    data = sim.tracker_flips(seed=seed)
    U, _ = derive_actions(data.t, data.X, data.demo, None)
    return data, replace(data, U=U, truth={}, metadata={})


def angle(data, truth) -> float:
    """Degrees between nhat's normal (k = 1) on ``data`` and the simulation's true normal."""
    n = StateIndependentConstraint(n_constraints=1).fit(data.X, data.U).constraint(data.X[:1])[0]
    return subspace_angle(n, truth.truth_per_sample("A")[0])


def found(data) -> dict[str, dict]:
    return {f["kind"]: f for f in data.metadata["files"][0].get("faults", [])}


@pytest.mark.parametrize("seed", [0, 2])
def test_flips_in_a_canonical_file_are_mirrored_back_and_reported(capsys, tmp_path, seed):
    truth, recorded = flipped(seed)
    injected = next(f for f in truth.metadata["faults"] if f["kind"] == "hemisphere_flip")
    path = tmp_path / "tracker.h5"
    write_demonstrations(path, recorded)
    data = load_demonstrations({"files": [str(path)]})
    faults = found(data)
    assert faults["hemisphere_flip"]["count"] == injected["count"]
    assert faults["hemisphere_flip"]["action"] == "mirrored"
    # the stored actions across each flip's two ends are dropped: a window of 9 at 50 Hz
    assert faults["action_near_fault"]["count"] == 2 * injected["count"]
    assert data.n_samples == recorded.n_samples - faults["action_near_fault"]["n_samples"]
    assert angle(data, truth) < 1.0
    kept = load_demonstrations({"files": [str(path)], "faults": {"flips": "keep"}})
    assert found(kept)["hemisphere_flip"]["action"] == "reported" and "action_near_fault" not in found(kept)
    assert angle(kept, truth) > 3.0  # what the flips did before: the normal pulled off
    # through the command line: warned with the count, the plane right
    out = tmp_path / "out"
    cfg = tmp_path / "c.yaml"
    cfg.write_text("learn-a: {method: nhat}\n")
    code = main(["learn-a", str(path), "-c", str(cfg), "-o", str(out), "--json"])
    captured = capsys.readouterr()
    assert code == 0, captured.err
    warnings = {w["code"]: w["message"] for w in json.loads(captured.out)["warnings"]}
    assert f"{injected['count']} hemisphere flip(s)" in warnings["hemisphere_flips"]
    assert "actions_near_faults" in warnings


def test_flips_in_an_h5py_layout_and_a_mat_file_with_derived_actions(tmp_path):
    truth, recorded = flipped(1)
    h5 = tmp_path / "log.h5"
    with h5py.File(h5, "w") as f:
        f.create_dataset("tracker/pos", data=recorded.X)
        f.create_dataset("tracker/t", data=recorded.t)
    mat = tmp_path / "log.mat"
    scipy.io.savemat(mat, {"pos": recorded.X, "t": recorded.t[:, None]})
    for path, where in ((h5, {"state": {"dataset": "tracker/pos"}, "time": {"dataset": "tracker/t"}}),
                        (mat, {"state": {"variable": "pos"}, "time": {"variable": "t"}})):
        cfg = {**where, "action": {"derive": "state"}, "files": [str(path)]}
        data = load_demonstrations(cfg)
        faults = found(data)
        assert faults["hemisphere_flip"]["count"] == 3, path
        assert "action_near_fault" not in faults  # derived after the repair: nothing to drop
        assert data.n_samples == recorded.n_samples
        assert angle(data, truth) < 1.0, path
        assert angle(load_demonstrations({**cfg, "faults": {"flips": "keep"}}), truth) > 3.0


def test_stamp_faults_and_spikes_in_an_h5py_layout(tmp_path):
    data = sim.tracker_plane(duration=40.0, seed=2)
    t, X = data.t.copy(), data.X.copy()
    t[700] = t[699]  # a repeated stamp
    X[1200] += [0.05, -0.04, 0.03]  # a 7-cm spike
    path = tmp_path / "log.h5"
    with h5py.File(path, "w") as f:
        f["pos"], f["t"] = X, t
    cfg = {"files": [str(path)], "state": {"dataset": "pos"}, "time": {"dataset": "t"},
           "action": {"derive": "state"}}
    read = load_demonstrations(cfg)
    faults = found(read)
    assert faults["bad_stamp"]["action"] == "restamped" and faults["bad_stamp"]["ranges"] == [[700, 701]]
    assert faults["spike"]["ranges"] == [[1200, 1201]] and read.n_samples == data.n_samples - 1
    assert angle(read, data) < 1.0
    with pytest.raises(Exception, match="not strictly increasing at sample 700"):
        load_demonstrations({**cfg, "faults": {"stamps": "keep"}})


def test_stored_actions_are_mirrored_only_when_they_follow_the_positions():
    truth, recorded = flipped(0)
    flips = repair_recording(recorded.t, recorded.X, recorded.U, recorded.demo, FaultOptions())
    flip = np.zeros(recorded.n_samples, bool)
    for a, b in next(f for f in flips.report if f["kind"] == "hemisphere_flip")["ranges"]:
        flip[a:b] = True
    inside = flip & ~np.convolve(np.diff(np.r_[False, flip]) != 0, np.ones(11), "same").astype(bool)
    repaired_u, _ = derive_actions(flips.t, flips.X, recorded.demo[flips.keep], None)
    sign = np.einsum("nq,nq->n", flips.U, repaired_u)[inside[flips.keep]]
    assert inside.sum() > 15 and (sign > 0).all()  # mirrored with the positions: along the repaired motion
    # actions of another sensor (the velocity of the true positions) are kept as stored
    true_x = np.where(flip[:, None], -recorded.X, recorded.X)
    other, _ = derive_actions(recorded.t, true_x, recorded.demo, None)
    kept = repair_recording(recorded.t, recorded.X, other, recorded.demo, FaultOptions())
    np.testing.assert_array_equal(kept.U, other[kept.keep])


@pytest.mark.parametrize("args", [["toy2d"], ["toy2d", "--policy", "limit_cycle"], ["two_link"],
                                  ["arm7", "--constraint", "jacobian"], ["varying_constraint"],
                                  ["tracker_plane", "--rate", "1000", "--duration", "20"],
                                  ["tracker_sphere"], ["arm_at_rest"]])
def test_clean_simulations_written_as_canonical_files_report_nothing(tmp_path, args):
    path = tmp_path / "sim.h5"
    assert main(["simulate", *args, "-o", str(path), "-q"]) == 0
    data = load_demonstrations({"files": [str(path)]})
    assert found(data) == {}
