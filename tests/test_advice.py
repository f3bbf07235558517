"""What a run advises and claims: the few-demonstrations advice names split_on_gap where the
recording pauses, and a policy learnt alone without ground truth is not called ok."""

import json

import numpy as np

from ccl_cli import diagnostics
from ccl_cli.cli import main
from ccl_cli.io import read_dataset


def _paused(path, stretches: int = 6, pause_s: float = 1.0) -> None:
    """One recording at 100 Hz of ``stretches`` straight strokes along x on the plane z = 0.1,
    separated by ``pause_s`` without samples (numpy.savetxt, header t,x,y,z)."""
    rng = np.random.default_rng(0)
    rows, t0 = [], 0.0
    for k in range(stretches):
        t = t0 + np.arange(150) * 0.01
        s = np.sin(np.linspace(0, np.pi, 150)) * 0.2
        rows.append(np.c_[t, s, 0.05 * k + 0 * s, 0.1 + 0 * s] + np.r_[0, rng.normal(0, 1e-4, 3)])
        t0 = t[-1] + pause_s
    np.savetxt(path, np.vstack(rows), delimiter=",", header="t,x,y,z", comments="")


def test_few_demonstrations_advice_names_split_on_gap_where_the_recording_pauses(tmp_path):
    path = tmp_path / "paused.csv"
    _paused(path)
    options = {"state": {"columns": ["x", "y", "z"]}, "action": {"derive": "state"}}
    data, _ = read_dataset(options, [path])
    [few] = [w["message"] for w in diagnostics.demonstrations(data) if w["code"] == "few_demos"]
    assert few.endswith("the recordings pause 5 times for 1 s or more: data.demos: {split_on_gap: 0.5} "
                        "cuts them at their pauses into 6 demonstrations")
    cut, _ = read_dataset(options | {"demos": {"split_on_gap": 0.5}}, [path])
    assert cut.n_demos == 6 and not [w for w in diagnostics.demonstrations(cut) if w["code"] == "few_demos"]
    # without pauses: the window advice, as before
    _paused(tmp_path / "continuous.csv", stretches=1)
    one, _ = read_dataset(options, [tmp_path / "continuous.csv"])
    [few] = [w["message"] for w in diagnostics.demonstrations(one) if w["code"] == "few_demos"]
    assert "data.demos: {window: S}" in few and "split_on_gap" not in few


def _toy_csvs(folder, with_truth: bool = False) -> None:
    from ccl_cli import simulate

    d = simulate.PROBLEMS["toy2d"](seed=0, n_demos=8)
    folder.mkdir()
    for k in d.demo_ids:
        sel = d.demo == k
        np.savetxt(folder / f"demo{k}.csv", np.c_[d.t[sel], d.X[sel], d.U[sel]], delimiter=",",
                   header="t,x1,x2,u1,u2", comments="")


def test_a_policy_learnt_alone_without_ground_truth_is_unjudged_not_ok(tmp_path, capsys):
    _toy_csvs(tmp_path / "toy")
    cfg = tmp_path / "c.yaml"
    cfg.write_text("data: {state: {columns: [x1, x2]}, action: {columns: [u1, u2]}}\noutput: {plots: false}\n"
                   "learn-a: {method: nhat, n_constraints: 1}\n")
    toy = str(tmp_path / "toy")
    assert main(["learn-pi", toy, "-c", str(cfg), "-o", str(tmp_path / "pi"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert summary["status"] == "unjudged" and summary["stages"]["learn-pi"]["status"] == "unjudged"
    assert summary["verdict"].startswith("unjudged: learn-pi: no metric to judge it by: the data has no "
                                         "true π")
    metrics = json.loads((tmp_path / "pi" / "metrics.json").read_text())["learn-pi"]
    assert metrics["status"] == "unjudged" and not metrics.get("train")
    assert main(["learn-pi", toy, "-c", str(cfg), "-o", str(tmp_path / "pi2"), "--strict",
                 "-q"]) == 1
    assert "--strict: the run is unjudged" in capsys.readouterr().err
    # after a learnt constraint it has NCPE_obs, and a verdict from it
    staged = tmp_path / "s.yaml"
    staged.write_text(cfg.read_text() + "stages: [learn-a, learn-pi]\n")
    assert main(["run", str(staged), "--data", toy, "-o", str(tmp_path / "r"), "--json"]) == 0
    summary = json.loads(capsys.readouterr().out)
    assert "NCPE_obs" in summary["stages"]["learn-pi"]["test"]
    assert summary["stages"]["learn-pi"]["status"] in ("ok", "poor")
