"""The default pipeline end to end (issue 17): ``ccl run`` with the README's stages
[learn-v, learn-a, learn-pi] and nothing but the data mapping, on recordings written by
``ccl simulate`` — learn-a's default (``auto``) against the simulations' ground truth."""

import json

import numpy as np

from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.io import write_demonstrations
from ccl_cli.metrics import subspace_angle


def run_default_pipeline(tmp_path, capsys, data_file) -> tuple[dict, dict]:
    """``ccl run`` of the default pipeline on ``data_file``: (--json summary, learn-a's metrics.json)."""
    cfg = tmp_path / "pipeline.yaml"
    cfg.write_text(f"data:\n  files: [{data_file}]\nstages: [learn-v, learn-a, learn-pi]\n")
    out = tmp_path / "out"
    capsys.readouterr()
    assert main(["run", str(cfg), "-o", str(out), "--json", "-q"]) == 0
    summary = json.loads(capsys.readouterr().out)
    return summary, json.loads((out / "metrics.json").read_text())["learn-a"]


def simulate(tmp_path, capsys, name: str, *args) -> str:
    path = tmp_path / f"{name}.h5"
    assert main(["simulate", name, "-o", str(path), "-q", *map(str, args)]) == 0
    capsys.readouterr()
    return str(path)


def test_plane_recording_gives_the_plane(tmp_path, capsys):
    path = simulate(tmp_path, capsys, "tracker_plane", "--seed", 1)
    summary, learn_a = run_default_pipeline(tmp_path, capsys, path)
    assert summary["stages"]["learn-a"]["method"] == "auto"
    assert learn_a["n_constraints"] == 1 and learn_a["selection"]["chosen"] == "nhat"
    assert learn_a["on"] == "u"  # the plane holds on the held-out u: no task part is needed
    truth = sim.tracker_plane(seed=1).truth["A"][0]
    assert subspace_angle(np.array(learn_a["constraint"]["rows"]), truth) < 1.5
    assert summary["stages"]["learn-a"]["test"]["NPPE"] < 1e-3
    # the table does not tilt: judged in the stretches where it holds, not in the free approach
    assert "constraint_varies" not in {w["code"] for w in summary["warnings"]}


def test_free_reaching_has_no_constraint(tmp_path, capsys):
    path = simulate(tmp_path, capsys, "free_reach", "--seed", 2, "--n-demos", 5)
    summary, learn_a = run_default_pipeline(tmp_path, capsys, path)
    assert learn_a["n_constraints"] == 0 and learn_a["selection"]["chosen"] == "none"
    assert learn_a["selection"]["reason"].startswith("no constraint")
    # every global candidate that was tried saw its first row move far beyond the noise, held
    # out; the constraint in stretches found its row quiet in too small a share of the time
    cands = learn_a["selection"]["candidates"]
    ratios = [c["noise_ratio"][0] for c in cands if c["noise_ratio"] and c["class"] != "stretches"]
    assert ratios and min(ratios) > 10
    stretches = next(c for c in cands if c["class"] == "stretches")
    assert stretches["k"] == 0 and stretches["time_share"] < stretches["min_time_share"]
    assert summary["stages"]["learn-a"]["test"]["NPOE"] == 0.0  # Ñ = I: the truth, N = I


def test_wiping_phase_of_the_arm_gives_the_table(tmp_path, capsys):
    """The wipe phases of arm_wipe (approach and retract cut off, as the phases say), written by
    ccl's own writer with how the velocities were derived."""
    d = sim.arm_wipe(n_demos=5, seed=3)
    wipe = sim.phase_subset(d, "wipe")
    path = tmp_path / "wipe.h5"
    provenance = {"simulate": "arm_wipe", "derivative": d.metadata["derivative"]}
    write_demonstrations(path, wipe, provenance=provenance)
    summary, learn_a = run_default_pipeline(tmp_path, capsys, str(path))
    assert learn_a["n_constraints"] == 1 and learn_a["selection"]["chosen"] in ("nhat", "per_demo")
    rows = np.array(learn_a["constraint"]["rows"]) if "rows" in learn_a["constraint"] else None
    if rows is None:  # one per demonstration: every demonstration's normal
        angles = list(learn_a["constraint"]["per_demo_angle_deg"].values())
    else:
        angles = [subspace_angle(rows, np.atleast_2d(d.metadata["normal"]))]
    assert max(angles) < 1.5


def test_whole_wiping_recording_gives_the_table_where_it_holds(tmp_path, capsys):
    """A whole wipe — approach, wipe, retract — as ``ccl simulate`` writes it, nothing cut: no
    constraint holds all along, the table's normal holds in the wipe stretches."""
    path = simulate(tmp_path, capsys, "arm_wipe", "--seed", 3, "--n-demos", 5)
    summary, learn_a = run_default_pipeline(tmp_path, capsys, path)
    assert learn_a["n_constraints"] == 1 and learn_a["selection"]["chosen"] == "manifold"  # in its phases
    assert learn_a["on"] == "u"
    assert "free motion elsewhere" in learn_a["selection"]["reason"]
    normal = np.atleast_2d(sim.arm_wipe(n_demos=5, seed=3).metadata["normal"])
    assert subspace_angle(np.array(learn_a["constraint"]["rows"]), normal) < 1.5
    assert summary["stages"]["learn-a"]["test"]["NPPE"] < 1e-3
    # the table does not tilt: judged in the stretches where it holds, not in the free approach
    assert "constraint_varies" not in {w["code"] for w in summary["warnings"]}


def test_on_auto_takes_w_when_the_task_part_moves_u_off_the_constraint(tmp_path, capsys):
    """The ncl tutorial's data (a task part in every sample, states not a trajectory): learn-v's w̃
    explains the held-out w̃ far better than any constraint on u explains u, so learn-a learns from w̃
    — and finds the true row (NPPE on the test demonstrations < 0.1); on u it would be 0.4."""
    from ccl_cli import simulate as sim
    from ccl_cli.cli import main
    from ccl_cli.io import write_demonstrations

    data = sim.toy2d(constraint="fixed", task=True, sampling="uniform", n_samples=1000, n_demos=10, seed=0)
    path = write_demonstrations(tmp_path / "ncl.h5", data)
    cfg = tmp_path / "c.yaml"
    cfg.write_text("stages: [learn-v, learn-a]\n")
    assert main(["run", str(cfg), "--data", str(path), "-o", str(tmp_path / "out"), "-q"]) == 0
    a = json.loads((tmp_path / "out" / "metrics.json").read_text())["learn-a"]
    assert a["on"] == "w" and "explain the test w̃" in a["on_reason"]
    assert a["n_constraints"] == 1 and a["test"]["NPPE"]["value"] < 0.1
