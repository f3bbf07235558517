"""Segmenting continuous recordings into demonstrations: windows, gaps, ranges, HDF5."""

import csv
import json
from pathlib import Path

import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.app.run import read_data
from ccl_cli.cli import main
from ccl_cli.config import from_mapping
from ccl_cli.errors import InputError
from ccl_cli.io import load_demonstrations, write_demonstrations
from ccl_cli.io.derivative import local_polynomial_derivative
from ccl_cli.io.segment import segment_ids

EPOCH_NS = 1_700_000_000_000_000_000


def write_tracker_csv(path, data, gap_after_s=None, gap_s=0.0):
    """The positions of a simulated recording as a Trakstar-style CSV export (csv module)."""
    t_ns = EPOCH_NS + np.round(data.t * 1e9).astype(np.int64)
    if gap_after_s is not None:
        t_ns[data.t > gap_after_s] += int(gap_s * 1e9)
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["%time", "x", "y", "z"])
        w.writerows([[int(s), *map(repr, x.tolist())] for s, x in zip(t_ns, data.X, strict=True)])
    return path


CSV_CFG = {"time": {"column": "%time", "unit": "ns"}, "state": {"columns": ["x", "y", "z"]},
           "action": {"derive": "state", "window": 9, "order": 2}}


def test_window_cuts_a_continuous_csv_recording_and_derives_inside_each_window(tmp_path):
    rec = sim.tracker_plane(duration=60.0, seed=0)
    path = write_tracker_csv(tmp_path / "finger.csv", rec)
    data = load_demonstrations({**CSV_CFG, "files": [str(path)], "demos": {"window": 4.0}})
    assert data.n_demos == 15
    assert np.bincount(data.demo).tolist() == [200] * 15
    # the derivative restarts at every window edge: equal to deriving each window alone
    for d in (0, 7, 14):
        rows = data.demo == d
        alone = local_polynomial_derivative(data.t[rows], data.X[rows], np.zeros(rows.sum(), int))
        np.testing.assert_allclose(data.U[rows], alone, atol=1e-12)
    np.testing.assert_allclose(data.X, rec.X, atol=1e-15)


@pytest.mark.parametrize(("seconds", "n_windows", "last"), [(61.0, 15, 250), (63.0, 16, 150)])
def test_a_short_tail_joins_the_window_before_it(seconds, n_windows, last):
    t = np.arange(int(seconds * 50)) / 50.0
    ids = segment_ids(t, {"window": 4}, "f.csv")
    assert ids.max() + 1 == n_windows
    assert np.bincount(ids)[-1] == last
    assert (np.diff(ids) >= 0).all()


def test_window_applies_within_gaps_and_ranges():
    t = np.r_[np.arange(500) / 50.0, 30.0 + np.arange(300) / 50.0]  # 10 s, a 20 s gap, 6 s
    by_gap = segment_ids(t, {"split_on_gap": 1.0, "window": 4.0}, "f")
    assert np.bincount(by_gap).tolist() == [200, 300, 300]  # 10 s → 4 + 6 (tail 2 s kept), 6 s → 6
    by_range = segment_ids(t, {"ranges": [[0.0, 8.99], [30.0, 36.0]], "window": 3.0}, "f")
    assert (by_range[(t > 8.99) & (t < 30.0)] == -1).all()
    assert np.bincount(by_range[by_range >= 0]).tolist() == [150, 150, 150, 150, 150]


@pytest.mark.parametrize("bad", [0, -2.0, True, "4"])
def test_bad_windows_are_refused_with_the_file_named(bad):
    with pytest.raises(InputError, match=r"^rec\.csv: demos\.window must be a number > 0 \(s\)"):
        segment_ids(np.arange(10.0), {"window": bad}, "rec.csv")
    with pytest.raises(InputError, match="unknown option"):
        segment_ids(np.arange(10.0), {"windows": 4}, "rec.csv")


def test_hdf5_recordings_are_cut_too_and_masks_follow_their_recording(tmp_path):
    rec = sim.tracker_sphere(duration=20.0, n_recordings=3, seed=1)
    path = write_demonstrations(tmp_path / "bowl.h5", rec, masks={"train": [0, 2], "test": [1]})
    data = load_demonstrations({"files": [str(path)], "demos": {"window": 5.0}})
    assert data.n_demos == 12 and data.n_samples == rec.n_samples
    np.testing.assert_array_equal(data.truth_per_sample("A"), rec.truth_per_sample("A"))
    cfg = from_mapping({"data": {"files": [str(path)], "demos": {"window": 5.0}}})
    cut, masks = read_data(cfg, None)
    assert cut.n_demos == 12
    assert masks == {"train": [0, 1, 2, 3, 8, 9, 10, 11], "test": [4, 5, 6, 7]}
    assert np.array_equal(cut.select_demos(masks["test"]).X, rec.select_demos([1]).X)


def test_run_with_windows_from_the_config(tmp_path, capsys):
    rec = sim.tracker_plane(duration=40.0, seed=2)
    write_tracker_csv(tmp_path / "finger.csv", rec)
    cfg = tmp_path / "cfg.yaml"
    cfg.write_text("data:\n  files: [finger.csv]\n  time: {column: '%time', unit: ns}\n"
                   "  state: {columns: [x, y, z]}\n  action: {derive: state}\n  demos: {window: 4}\n"
                   "learn-a: {method: nhat}\nstages: [learn-a]\n")
    assert main(["run", str(cfg), "-o", str(tmp_path / "out"), "--json", "-q"]) == 0
    capsys.readouterr()
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run["data"]["demos"] == 10 and run["data"]["test"] == 3 * 200  # 3 of 10 windows held out
    bad = tmp_path / "bad.yaml"
    bad.write_text(cfg.read_text().replace("window: 4", "window: four"))
    assert main(["run", str(bad), "-o", str(tmp_path / "out2"), "-q"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "window" in err[0]


def test_shipped_continuous_bowl_recording_windows_or_blocks(tmp_path, capsys):
    """configs/trakstar_bowl.yaml: one 60-s recording cut into 4-s windows → split by window,
    k = 1 and held-out NPOE < 0.03; without the cut it gets a block split and few_demos."""
    root = Path(__file__).resolve().parent.parent
    cfg = root / "configs" / "trakstar_bowl.yaml"
    assert main(["run", str(cfg), "-o", str(tmp_path / "w"), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["validation"]["kind"] == "demonstrations" and summary["warnings"] == []
    assert summary["stages"]["learn-a"]["n_constraints"] == 1
    assert summary["stages"]["learn-a"]["test"]["NPOE"] < 0.03
    whole = tmp_path / "whole.yaml"
    whole.write_text(cfg.read_text().replace("  demos: {window: 4}\n", "").replace(
        "../sample_data/", f"{root / 'sample_data'}/"))
    assert main(["run", str(whole), "-o", str(tmp_path / "b"), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["validation"]["kind"] == "blocks"
    assert [w["code"] for w in summary["warnings"]] == ["few_demos"]


@pytest.mark.parametrize(("rate", "window"), [(50.0, 9), (100.0, 17), (500.0, 81), (2000.0, 101)])
def test_default_derivative_window_spans_the_same_time_at_any_rate(tmp_path, rate, window):
    """Without data.action.window the reader derives over ±0.08 s at the recording's median
    rate (capped at 101 samples), records the window and why, and guards the time-block split
    with it; at 500 Hz that cuts the velocity noise several-fold against a fixed 9 samples."""
    rec = sim.tracker_plane(duration=8.0, rate=rate, noise=1e-3, seed=1)
    path = write_tracker_csv(tmp_path / "finger.csv", rec)
    cfg = {k: v for k, v in CSV_CFG.items() if k != "action"} | {"action": {"derive": "state"}}
    data = load_demonstrations({**cfg, "files": [str(path)]})
    info = data.metadata["files"][0]["action"]
    assert info["window"] == window and info["order"] == 2
    assert f"{rate:.4g} Hz" in info["window_rule"]
    true_u = sim.tracker_plane(duration=8.0, rate=rate, noise=0.0, seed=1).U
    err_default = np.sqrt(np.mean((data.U - true_u) ** 2))
    if rate == 500.0:
        fixed = load_demonstrations({**cfg, "files": [str(path)],
                                     "action": {"derive": "state", "window": 9}})
        err_fixed = np.sqrt(np.mean((fixed.U - true_u) ** 2))
        assert err_default < err_fixed / 5
    from ccl_cli.app.stages import guard_gap
    assert guard_gap(from_mapping({"data": cfg}).spec, data) == max(window, 10)
    from ccl_cli.app.provenance import derived_actions  # the report.md / run.json line
    assert f"window {window} samples: default: ±0.08 s at the median rate" in derived_actions(data.metadata)
