"""Typed facts on Demonstrations (issue 27): how the actions were made (``derivative``) and what
fault repair did to each sample (``repair``), set by the reader or simulator that knows them and
read as fields — checked here against what was written and injected."""

import json

import numpy as np
import pytest
from test_faults_read import export
from test_segment import CSV_CFG, write_tracker_csv

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.dataset import Demonstrations, Derivative, Repair
from ccl_cli.io import load_demonstrations, write_demonstrations


# -- how the actions were made ---------------------------------------------------------------------
def test_a_reader_that_derives_the_actions_says_how(tmp_path):
    rec = sim.tracker_plane(duration=20.0, seed=0)
    path = write_tracker_csv(tmp_path / "f.csv", rec)
    data = load_demonstrations({**CSV_CFG, "files": [str(path)]})
    assert data.derivative == Derivative(True, 9, 2, "data.action.window")
    chosen = load_demonstrations({**CSV_CFG, "action": {"derive": "state", "order": 3}, "files": [str(path)]})
    # no window given: ±0.08 s at the 50-Hz rate of the file, 9 samples, and the reason in words
    assert chosen.derivative.derived and (chosen.derivative.window, chosen.derivative.order) == (9, 3)
    assert chosen.derivative.rule.startswith("default: ±0.08 s at the median rate 50 Hz")
    assert data.derivative.gain(0.02) == pytest.approx(1 / (60 * 0.02**2))  # Σc² = 1/(Δt² Σk²), k = −4…4


def test_recorded_actions_are_said_so_and_the_learners_forms_are_read(tmp_path):
    rec = sim.tracker_plane(duration=10.0, seed=1)
    path = tmp_path / "xu.csv"
    np.savetxt(path, np.c_[rec.t, rec.X, rec.U], delimiter=",", header="t,x,y,z,u,v,w", comments="")
    columns = {"time": {"column": "t"}, "state": {"columns": ["x", "y", "z"]},
               "action": {"columns": ["u", "v", "w"]}}
    data = load_demonstrations({"files": [str(path)], **columns})
    assert data.derivative == Derivative(False) and data.derivative.known
    assert Derivative.of(False) == Derivative(False) and Derivative.of(None) == Derivative()
    assert Derivative.of({"window": 21, "order": 3}) == Derivative(True, 21, 3)
    with pytest.raises(Exception, match="derivative must say how the actions were made"):
        Derivative.of("derived")


def test_a_simulated_file_keeps_how_its_velocities_were_derived(tmp_path):
    path = tmp_path / "plane.h5"
    assert main(["simulate", "tracker_plane", "-o", str(path), "--duration", "10", "--rate", "200",
                 "--json"]) == 0
    data = load_demonstrations({"files": [str(path)]})
    assert data.derivative == Derivative(True, 33, 2)  # ±0.08 s at 200 Hz
    # joined files: the first that says
    plain = Demonstrations(data.X, data.U, demo=data.demo, t=data.t)
    assert Demonstrations.concatenate([plain, data]).derivative == data.derivative
    assert Demonstrations.concatenate([plain, plain]).derivative == Derivative()


def test_the_guard_gap_of_a_run_is_the_derivative_window(tmp_path, capsys):
    """A single recording is split into held-out time blocks; the samples dropped at each
    boundary are the derivative window the file says it was made with (33 at 200 Hz)."""
    path = tmp_path / "plane.h5"
    main(["simulate", "tracker_plane", "-o", str(path), "--duration", "20", "--rate", "200", "--json"])
    capsys.readouterr()
    cfg = tmp_path / "c.yaml"
    cfg.write_text("learn-a: {method: nhat}\n")
    assert main(["learn-a", str(path), "-c", str(cfg), "-o", str(tmp_path / "out"), "--json"]) == 0
    split = json.loads(capsys.readouterr().out)["validation"]
    assert split["kind"] == "blocks" and split["gap"] == 33 and split["n_dropped_samples"] == 3 * 33


# -- what fault repair did -------------------------------------------------------------------------
def injected(data, kind: str) -> np.ndarray:
    """The samples (indices of the recording) of the faults of ``kind`` a simulator injected."""
    f = next((f for f in data.metadata["faults"] if f["kind"] == kind), None)
    return np.array([], int) if f is None else np.concatenate([np.arange(a, b) for a, b in f["ranges"]])


def test_fault_repair_is_recorded_for_every_sample(tmp_path):
    data = sim.tracker_flips(seed=0, n_spikes=3, stamp_faults=("duplicate", "repeat"))
    path = tmp_path / "trakstar.csv"
    export(path, data)
    read = load_demonstrations({"files": [str(path)], "state": {"columns": ["x", "y", "z"]}})
    r = read.repair
    assert len(r.done) == data.n_samples == read.n_samples + 4  # a duplicate and three spikes dropped
    assert r.counts() == {"kept": {"": 4442}, "mirrored": {"hemisphere_flip": 54},
                          "restamped": {"bad_stamp": 1}, "dropped": {"duplicate_sample": 1, "spike": 3}}
    flips, spikes = injected(data, "hemisphere_flip"), injected(data, "spike")
    assert (r.actions()[flips] == "mirrored").all() and (r.reasons()[flips] == "hemisphere_flip").all()
    assert (r.actions()[spikes] == "dropped").all() and (r.row[spikes] == -1).all()
    # each kept sample's row: the repaired position (a mirrored one is the recorded one negated)
    kept = r.row >= 0
    assert (np.diff(r.row[kept]) == 1).all() and r.row[kept][-1] == read.n_samples - 1
    np.testing.assert_allclose(read.X[r.row[flips]], -data.X[flips], atol=1e-6)
    done, why = r.of_rows(read.n_samples)
    assert (done == "mirrored").sum() == 54 and set(why[done == "kept"]) == {""}
    # a part of the data keeps each sample's place in it
    part = read.subset(read.t > 40.0)
    inside = part.repair.row >= 0
    assert inside.sum() == part.n_samples
    np.testing.assert_array_equal(part.X[part.repair.row[inside]], read.X[r.row[inside]])


def test_faults_kept_as_recorded_are_recorded_so(tmp_path):
    data = sim.tracker_flips(seed=3)
    path = tmp_path / "trakstar.csv"
    export(path, data)
    read = load_demonstrations({"files": [str(path)], "state": {"columns": ["x", "y", "z"]},
                                "faults": {"flips": "keep"}})
    flips = injected(data, "hemisphere_flip")
    assert set(read.repair.actions()) == {"kept"}
    assert (read.repair.reasons()[flips] == "hemisphere_flip").all()
    np.testing.assert_allclose(read.X[flips], data.X[flips], atol=1e-6)


def test_a_canonical_file_with_stored_actions_records_the_actions_dropped_near_a_fault(tmp_path):
    data = sim.tracker_flips(seed=0, n_spikes=2)
    write_demonstrations(tmp_path / "f.h5", data)
    read = load_demonstrations({"files": [str(tmp_path / "f.h5")]})
    r = read.repair
    found = {f["kind"]: f["n_samples"] for f in read.metadata["files"][0]["faults"]}
    assert found == {"hemisphere_flip": 54, "spike": 2, "action_near_fault": 76}
    # the 54 flipped samples were mirrored back, but the stored actions within a derivative window
    # of a flip's ends went with their samples: 30 of the 54 among the 76
    assert r.counts() == {"kept": {"": 4398}, "mirrored": {"hemisphere_flip": 24},
                          "dropped": {"spike": 2, "action_near_fault": 76}}
    flips = injected(data, "hemisphere_flip")
    assert set(r.actions()[flips]) == {"mirrored", "dropped"}
    assert (r.row >= 0).sum() == read.n_samples == data.n_samples - 78


def test_joined_records_keep_each_files_rows():
    a = Repair(np.array([0, 3, 1], np.uint8), np.array([0, 1, 2], np.uint8), ("", "spike", "hemisphere_flip"),
               np.array([0, -1, 1]))
    b = Repair.untouched(2)
    joined = Repair.join([(a, 2), (None, 1), (b, 2)])
    assert joined.faults == ("", "spike", "hemisphere_flip")
    assert joined.actions().tolist() == ["kept", "dropped", "mirrored", "kept", "kept", "kept"]
    assert joined.reasons().tolist() == ["", "spike", "hemisphere_flip", "", "", ""]
    assert joined.row.tolist() == [0, -1, 1, 2, 3, 4]
    assert Repair.join([(None, 3)]) is None
