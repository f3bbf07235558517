"""``ccl predict`` and ``ccl evaluate`` on recordings a model has not seen (issues 29, 30): one row
out per sample read — repaired samples flagged (mirrored, restamped, dropped and filled) and none
dropped silently — the model's rule for new data stated, the same answer on a second run, for
every kind of constraint model learn-a writes; a recording given twice is refused."""

from __future__ import annotations

import csv
import json
import shutil
from pathlib import Path

import h5py
import numpy as np
import pytest

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io.canonical import write_demonstrations
from ccl_cli.learn import constraint as C
from ccl_cli.models import save_model

T0_NS = 1_700_000_000_000_000_000
SAMPLES = Path(__file__).resolve().parents[1] / "sample_data"
CONFIG = "data:\n  time: {column: stamp, unit: ns}\n  state: {columns: [x, y, z]}\n"


def export(path, data) -> None:
    """A tracker's CSV export: stamp (int ns), x, y, z (m, 9 digits)."""
    with open(path, "w", newline="") as f:
        w = csv.writer(f)
        w.writerow(["stamp", "x", "y", "z"])
        for stamp, x in zip(T0_NS + np.round(data.t * 1e9).astype(np.int64), data.X, strict=True):
            w.writerow([int(stamp), *(f"{v:.9f}" for v in x)])


def ccl(capsys, *argv) -> tuple[int, dict, str]:
    code = main([str(a) for a in argv])
    out = capsys.readouterr()
    return code, json.loads(out.out) if out.out.strip() else {}, out.err


@pytest.fixture(scope="module")
def faulty(tmp_path_factory):
    """A 12-s tracker recording with 3 hemisphere flips, 2 spikes, a duplicated sample, a bad and a
    backward stamp, exported as CSV, with a model learnt on a clean recording of the same plane."""
    tmp = tmp_path_factory.mktemp("faulty")
    data = sim.tracker_flips(n_spikes=2, stamp_faults=("repeat", "duplicate", "back"), duration=12.0, seed=1)
    export(tmp / "faulty.csv", data)
    export(tmp / "clean.csv", sim.tracker_plane(duration=20.0, seed=2))
    (tmp / "c.yaml").write_text(CONFIG + "learn-a: {method: nhat}\n")
    assert main(["learn-a", str(tmp / "clean.csv"), "-c", str(tmp / "c.yaml"), "-o", str(tmp / "a"),
                 "-q"]) == 0
    faults = {f["kind"]: f["ranges"] for f in data.metadata["faults"]}
    return tmp, data, faults


def test_predict_gives_one_row_per_sample_read_with_the_repairs_flagged(capsys, faulty):
    tmp, data, faults = faulty
    raw = np.loadtxt(tmp / "faulty.csv", delimiter=",", skiprows=1)[:, 1:]
    code, summary, err = ccl(capsys, "predict", tmp / "a" / "model.h5", tmp / "faulty.csv", "-c",
                             tmp / "c.yaml", "-o", tmp / "p.h5", "--json")
    assert code == 0, err
    n = len(raw)
    assert summary["samples"] == summary["samples_read"] == n == 601 and summary["left_out"] == 0
    flipped = sum(b - a for a, b in faults["hemisphere_flip"])
    assert summary["repaired"] == {"mirrored": {"hemisphere_flip": flipped},
                                   "filled": {"spike": 2, "duplicate_sample": 1},
                                   "restamped": {"bad_stamp": 1, "backward_stamp": 1}}
    assert summary["rule"]["rule"] == "as fitted" and "one row per sample read" in summary["fill_rule"]
    with h5py.File(tmp / "p.h5") as f:
        sample, x, N, t = f["sample"][()], f["x"][()], f["N"][()], f["t"][()]
        repair, fault = f["repair"].asstr()[()], f["fault"].asstr()[()]
        assert json.loads(f.attrs["rule"])["rule"] == "as fitted"
    assert sample.tolist() == list(range(n)) and len(x) == len(N) == n
    mirrored = np.zeros(n, bool)
    for a, b in faults["hemisphere_flip"]:
        mirrored[a:b] = True
    assert np.array_equal(repair == "mirrored", mirrored) and set(fault[mirrored]) == {"hemisphere_flip"}
    np.testing.assert_allclose(x[mirrored], -raw[mirrored], atol=1e-15)  # predicted at the repaired state
    np.testing.assert_array_equal(x[repair == "kept"], raw[repair == "kept"])
    for k in (a for a, _ in faults["spike"]):  # a dropped spike: the row of the sample before it, held
        assert repair[k] == "filled" and fault[k] == "spike"
        assert np.array_equal(x[k], x[k - 1]) and np.array_equal(N[k], N[k - 1]) and t[k] == t[k - 1]
        np.testing.assert_array_equal(x[k], raw[k - 1])  # a state that was recorded ...
        assert np.abs(x[k] - raw[k]).max() > 0.01  # ... not the spike (2–8 cm off)
    dup = faults["duplicate_sample"][0][0]  # a repeated sample: the one it repeats
    assert repair[dup] == "filled" and fault[dup] == "duplicate_sample"
    assert np.array_equal(raw[dup], raw[dup - 1])
    np.testing.assert_array_equal(x[dup], raw[dup])
    # the CSV holds the same rows, the flags as text
    assert main(["predict", str(tmp / "a" / "model.h5"), str(tmp / "faulty.csv"), "-c", str(tmp / "c.yaml"),
                 "-o", str(tmp / "p.csv"), "-q"]) == 0
    with open(tmp / "p.csv") as f:
        rows = list(csv.DictReader(f))
    assert len(rows) == n and [r["repair"] for r in rows] == repair.tolist()
    assert [int(r["sample"]) for r in rows] == list(range(n)) and rows[0]["demo"] == "0"


def test_samples_outside_the_configured_demonstrations_are_counted_not_dropped_silently(capsys, faulty):
    tmp, _, _ = faulty
    (tmp / "cut.yaml").write_text(CONFIG + "  demos: {ranges: {0: [[1.0, 9.0]]}}\n")
    code, summary, err = ccl(capsys, "predict", tmp / "a" / "model.h5", tmp / "faulty.csv", "-c",
                             tmp / "cut.yaml", "-o", tmp / "cut.h5", "--json")
    assert code == 0, err
    with h5py.File(tmp / "cut.h5") as f:
        t, sample = f["t"][()], f["sample"][()]
    # 8 s at 50 Hz and the duplicated sample (2.45 s) filled (the stamps from the range's start)
    assert summary["samples"] == len(t) == 402
    assert summary["repaired"]["filled"] == {"spike": 2, "duplicate_sample": 1}
    assert summary["samples"] + summary["left_out"] == summary["samples_read"] == 601
    assert t.max() - t.min() == pytest.approx(8.0, abs=0.03)
    assert np.all(np.diff(sample) > 0)


def test_the_warnings_report_and_inspect_name_each_repair_by_demonstration_and_time(capsys, faulty):
    tmp, data, faults = faulty
    code, summary, err = ccl(capsys, "learn-a", tmp / "faulty.csv", "-c", tmp / "c.yaml", "-o", tmp / "r",
                             "--json")
    assert code == 0, err
    spikes = next(w["message"] for w in summary["warnings"] if w["code"] == "spikes")
    times = [data.t[a] for a, _ in faults["spike"]]
    said = ", ".join(f"{s:.2f} s" for s in times)
    assert f"2 samples dropped — demonstration 0: 2 samples at {said}" in spikes
    record = json.loads((tmp / "r" / "run.json").read_text())["data"]["repairs"]
    flips = next(r for r in record if r["fault"] == "hemisphere_flip")
    assert flips["demo"] == 0 and flips["action"] == "mirrored"
    stretches = [[data.t[a], data.t[b - 1]] for a, b in faults["hemisphere_flip"]]
    np.testing.assert_allclose(flips["times"], stretches, atol=1e-9)
    report = (tmp / "r" / "report.md").read_text()
    assert "- sensor-fault repair" in report and "demonstration 0: 2 dropped (spike) at" in report
    code, info, err = ccl(capsys, "inspect", tmp / "faulty.csv", "-c", tmp / "c.yaml", "--json")
    assert code == 0, err
    assert info["as_configured"]["repairs"] == record
    assert main(["inspect", str(tmp / "faulty.csv"), "-c", str(tmp / "c.yaml")]) == 0
    assert "repaired: demonstration 0: 2 sample(s) dropped (spike) at" in capsys.readouterr().out
    code, model, err = ccl(capsys, "inspect", tmp / "r" / "model.h5", "--json")  # what it was trained on
    assert code == 0 and model["training"]["repairs"] == record, err
    # two files: the repairs of the second are its demonstration's, 1
    code, both, err = ccl(capsys, "learn-a", tmp / "clean.csv", tmp / "faulty.csv", "-c", tmp / "c.yaml",
                          "-o", tmp / "r2", "--json", "-q")
    assert code == 0, err
    spikes = [w["message"] for w in both["warnings"] if w["code"] == "spikes"]
    assert len(spikes) == 1 and spikes[0].startswith(f"{tmp / 'faulty.csv'}: 2 spike(s)")
    assert f"demonstration 1: 2 samples at {said}" in spikes[0]


#: Every kind of constraint model learn-a writes (auto's winners saved as the model they are):
#: name, learner, its data (by seed), the rule it states for a recording it has not seen.
KINDS = [
    ("none", C.NoConstraint, lambda s: sim.free_reach(n_demos=3, seed=s), "as fitted"),
    ("nhat", C.StateIndependentConstraint, lambda s: sim.tracker_plane(duration=15.0, n_recordings=3, seed=s),
     "as fitted"),
    ("alpha", lambda: C.StateDependentConstraint(tune=False),
     lambda s: sim.toy2d(constraint="parabola", seed=s, n_demos=24), "as fitted"),
    ("lambda", lambda: C.KnownFeatureConstraint(features="arm2", tune=False, n_restarts=1),
     lambda s: sim.two_link(seed=s, n_demos=12, n_steps=20), "as fitted"),
    ("linear", lambda: C.LinearConstraint(regressors="polynomial", degree=1, tune=False),
     lambda s: sim.toy2d(constraint="parabola", seed=s, n_demos=12), "as fitted"),
    ("per_demo", lambda: C.PerWindow(window=None), lambda s: sim.varying_constraint(seed=s),
     "rows fitted per stretch"),
    ("per_window", lambda: C.PerWindow(window=6.0), lambda s: sim.tracker_tilt(seed=s, duration=36.0),
     "rows fitted per stretch"),
    ("per_segment", C.PerSegment, lambda s: sim.tracker_tilt(mode="steps", seed=s, duration=36.0),
     "rows fitted per stretch"),
    ("stretches", C.ConstraintInStretches, lambda s: sim.arm_wipe(n_demos=4, seed=s), "stretches classified"),
    ("manifold", lambda: C.ManifoldConstraint(family="sphere", n_constraints=1),
     lambda s: sim.tracker_sphere(duration=15.0, n_recordings=3, seed=s), "as fitted"),
    ("manifold per demonstration",
     lambda: C.PerDemonstration(C.ManifoldConstraint(family="sphere", n_constraints=1)),
     lambda s: sim.tracker_sphere(duration=15.0, n_recordings=3, seed=s), "fitted per demonstration"),
]


@pytest.mark.parametrize(("name", "make", "data", "rule"), KINDS, ids=[k[0] for k in KINDS])
def test_every_model_kind_applies_to_an_unseen_recording_with_one_row_per_sample(
        capsys, tmp_path, name, make, data, rule):
    train, new = data(1), data(2)
    model = make().fit(train.X, train.U, groups=train.demo, t=train.t, derivative=train.derivative)
    save_model(tmp_path / "model.h5", model)
    write_demonstrations(tmp_path / "new.h5", new)
    runs = []
    for i in range(2):  # the same answer on a second run
        code, ev, err = ccl(capsys, "evaluate", tmp_path / "model.h5", tmp_path / "new.h5", "--json", "-q")
        assert code == 0, err
        code, pred, err = ccl(capsys, "predict", tmp_path / "model.h5", tmp_path / "new.h5", "-o",
                              tmp_path / f"p{i}.h5", "--json", "-q")
        assert code == 0, err
        with h5py.File(tmp_path / f"p{i}.h5") as f:
            runs.append((ev["metrics"], {k: f[k][()] for k in ("N", "w", "x", "demo", "sample")}))
        assert ev["rule"]["rule"] == pred["rule"]["rule"] == rule
        assert ev["rule"]["words"] == model.new_data_rule.words
        assert pred["samples"] == pred["samples_read"] == new.n_samples and pred["left_out"] == 0
        assert ("note" in pred) == (rule != "as fitted")  # a fit on the new data is said
    (m0, p0), (m1, p1) = runs
    assert m0 == m1 and all(np.array_equal(p0[k], p1[k]) for k in p0)
    assert len(p0["N"]) == new.n_samples and np.array_equal(p0["sample"], np.arange(new.n_samples))
    q = new.n_action
    assert np.allclose(np.einsum("nij,njk->nik", p0["N"], p0["N"]), p0["N"], atol=1e-8)  # projections
    assert p0["N"].shape == (new.n_samples, q, q)


def test_a_recording_given_twice_is_refused(capsys, tmp_path, faulty):
    src, _, _ = faulty
    one, copy, link = tmp_path / "one.csv", tmp_path / "copy.csv", tmp_path / "link.csv"
    shutil.copy(src / "clean.csv", one)
    shutil.copy(one, copy)
    link.symlink_to(one)
    cfg = src / "c.yaml"
    for files, said in (([one, one], f"{one} is given twice"),
                        ([tmp_path / "*.csv", one], "are the same file"),  # a glob and a name
                        ([one, link], f"{one} and {link} are the same file"),
                        ([one, copy], f"{one} and {copy} have the same content (sha256")):
        code, _, err = ccl(capsys, "learn-a", *files, "-c", cfg, "-o", tmp_path / "out", "-q")
        assert code == 2 and said in err and "give each once" in err
        assert len(err.strip().splitlines()) == 1 and "Traceback" not in err
    assert not (tmp_path / "out").exists()
    code, _, err = ccl(capsys, "predict", src / "a" / "model.h5", one, copy, "-c", cfg, "-o",
                       tmp_path / "p.h5")
    assert code == 2 and "have the same content" in err and not (tmp_path / "p.h5").exists()


def test_learn_a_defaults_on_real_hinge_logs_then_two_logs_it_has_not_seen(capsys, tmp_path):
    """learn-a's own file on the shipped dishwasher logs 001–006 (auto: a circle per demonstration,
    k = 2), evaluated and predicted on 007 and 008: one row per line of those files, the rule
    stated, the same answer twice, N a rank-1 projection (two constraints in 3-D) everywhere."""
    logs = sorted((SAMPLES / "articulation" / "dishwasher").glob("*.log"))
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data:\n  state: {columns: [0, 1, 2]}\n  action: {derive: state}\n  time: {rate: 10}\n")
    code, res, err = ccl(capsys, "learn-a", *logs[:6], "-c", cfg, "-o", tmp_path / "a", "--json", "-q")
    assert code == 0 and res["stages"]["learn-a"]["n_constraints"] == 2, err
    lines = sum(len(f.read_text().split()) // 3 for f in logs[6:])  # three numbers a line
    answers = []
    for i in range(2):
        code, ev, err = ccl(capsys, "evaluate", tmp_path / "a" / "model.h5", *logs[6:], "-c", cfg, "--json",
                            "-q")
        assert code == 0, err
        code, pred, err = ccl(capsys, "predict", tmp_path / "a" / "model.h5", *logs[6:], "-c", cfg, "-o",
                              tmp_path / f"p{i}.h5", "--json", "-q")
        assert code == 0, err
        assert ev["rule"] == pred["rule"] and pred["rule"]["rule"] == "fitted per demonstration"
        assert pred["samples"] == pred["samples_read"] == lines and pred["repaired"] == {} and "note" in pred
        with h5py.File(tmp_path / f"p{i}.h5") as f:
            answers.append((ev["metrics"], f["N"][()]))
    assert answers[0][0] == answers[1][0] and np.array_equal(answers[0][1], answers[1][1])
    N = answers[0][1]
    assert len(N) == lines and np.allclose(np.trace(N, axis1=1, axis2=2), 1.0, atol=1e-9)
