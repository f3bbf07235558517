"""Data diagnostics: coded warnings on data at rest, constant joints, noisy or low-rank
actions, few/short demonstrations and bad stamps — and where they show up."""

import json

import numpy as np
import pytest
from test_segment import CSV_CFG, write_tracker_csv

from ccl_cli import diagnostics as D
from ccl_cli import simulate as sim
from ccl_cli.cli import main
from ccl_cli.dataset import Demonstrations, Derivative
from ccl_cli.io import load_demonstrations
from ccl_cli.io.derivative import local_polynomial_derivative
from ccl_cli.learn.constraint import StateIndependentConstraint


def codes(warnings):
    return [w["code"] for w in warnings]


def test_a_robot_at_rest_gets_no_motion_and_its_constant_joints_are_named():
    data = sim.arm_at_rest(seed=0)
    warnings = D.check_data(data)
    assert "no_motion" in codes(warnings)
    const = [w["message"] for w in warnings if w["code"] == "constant_dimension"]
    assert len(const) == 2  # the finger joints, as states and as actions
    assert "finger_joint_1 = 0.04, finger_joint_2 = 0.04" in const[0]
    assert "dfinger_joint_1/dt = 0, dfinger_joint_2/dt = 0" in const[1]
    assert not any("lwr_arm" in m for m in const)


def test_a_finger_at_rest_read_from_csv_gets_no_motion(tmp_path):
    rng = np.random.default_rng(0)
    n = 3000
    X = np.array([0.30, -0.05, 0.12]) + rng.normal(scale=1e-3, size=(n, 3))
    still = Demonstrations(X=X, U=np.zeros_like(X), t=np.arange(n) / 50.0)
    path = write_tracker_csv(tmp_path / "rest.csv", still)
    data = load_demonstrations({**CSV_CFG, "files": [str(path)], "demos": {"window": 4.0}})
    assert "no_motion" in codes(D.check_data(data))
    assert D.noise_levels(data)["derived"] is True
    assert 0.8 < D.noise_levels(data)["snr_u"] < 1.3  # the derived velocity is all noise


@pytest.mark.parametrize("noise", [0.0, 2e-4, 1e-3, 2e-3])
@pytest.mark.parametrize("problem", ["tracker_plane", "tracker_sphere"])
def test_moving_tracker_recordings_get_no_motion_warning(problem, noise):
    data = sim.PROBLEMS[problem](noise=noise, duration=60.0, seed=1)
    assert codes(D.check_data(data)) == ["few_demos"]  # one continuous recording
    assert D.noise_levels(data)["snr_u"] > 3 * D.NO_MOTION_SNR


@pytest.mark.parametrize("make", [
    lambda: sim.toy2d(seed=0), lambda: sim.two_link(seed=0), lambda: sim.arm7(seed=0),
    lambda: sim.toy2d(sampling="uniform", n_samples=1000, n_demos=10, task=True, seed=0),
    lambda: sim.varying_constraint(snr_db=20.0, seed=0)])
def test_reference_problems_raise_no_data_warnings(make):
    assert D.check_data(make()) == []


def test_velocities_derived_with_too_short_a_window_are_noisy_actions():
    noisy = sim.tracker_plane(rate=500.0, window=9, duration=20.0, seed=2)
    found = D.check_data(noisy)
    assert "noisy_actions" in codes(found) and "no_motion" not in codes(found)
    assert "widen data.action.window" in found[codes(found).index("noisy_actions")]["message"]
    assert "noisy_actions" not in codes(D.check_data(sim.tracker_plane(rate=500.0, duration=20.0, seed=2)))


def test_noise_estimates_match_the_simulated_noise():
    data = sim.tracker_plane(noise=1e-3, duration=60.0, seed=3)
    lv = D.noise_levels(data)
    np.testing.assert_allclose(np.sqrt(lv["x_noise"]), 1e-3, rtol=0.1)
    dt = 1 / 50.0
    assert data.derivative == Derivative(True, 9, 2)  # the simulator says how it made the velocities
    assert data.derivative.gain(dt) == pytest.approx(1 / (60 * dt**2))  # Σc² = 1/(Δt² Σk²)
    normal = data.U @ data.truth["A"][0]  # the velocity across the plane is pure noise
    assert np.sqrt(lv["u_noise"].mean()) == pytest.approx(normal.std(), rel=0.1)


def test_few_and_short_demonstrations():
    data = sim.toy2d(seed=0, n_demos=3)
    assert codes(D.demonstrations(data)) == ["few_demos"]
    cut = data.subset(~((data.demo == 1) & (np.arange(len(data.demo)) % 20 > 4)))
    found = D.demonstrations(cut)
    assert codes(found) == ["few_demos", "short_demos"]
    assert "1 of 3 demonstrations have fewer than 10 samples (shortest 5)" in found[1]["message"]


def test_duplicate_and_jittery_stamps():
    clean = sim.tracker_plane(duration=20.0, seed=4)
    assert D.stamps(clean) == []
    jittery = sim.tracker_plane(duration=20.0, jitter=2e-3, seed=4)  # 2 ms on a 20 ms period
    found = D.stamps(jittery)
    assert codes(found) == ["jittery_stamps"] and "by 14 % around 0.0201 s (49.8 Hz)" in found[0]["message"]
    assert D.stamps(sim.tracker_plane(duration=20.0, jitter=2e-4, seed=4)) == []
    t = clean.t.copy()
    t[[100, 200]] = t[[99, 199]]
    dup = Demonstrations(X=clean.X, U=clean.U, demo=clean.demo, t=t)
    assert codes(D.stamps(dup)) == ["duplicate_stamps"]
    assert D.stamps(dup)[0]["message"].startswith("2 samples")
    # demonstrations at different but steady rates (0.0097 s and 0.0135 s, as a real-time loop
    # per demonstration) are not jittery; the same spread inside one demonstration is
    n = 200
    t2 = np.r_[np.arange(n) * 0.0097, np.arange(n) * 0.0135]
    steady = Demonstrations(X=np.zeros((2 * n, 1)), U=np.zeros((2 * n, 1)), demo=np.repeat([0, 1], n), t=t2)
    assert D.stamps(steady) == []
    mixed = np.cumsum(np.array([0.0097, 0.0116, 0.0135])[np.arange(2 * n) % 3])
    one = Demonstrations(X=np.zeros((2 * n, 1)), U=np.zeros((2 * n, 1)), demo=np.zeros(2 * n, int), t=mixed)
    assert codes(D.stamps(one)) == ["jittery_stamps"]


def test_low_rank_actions_when_few_demonstrations_each_explore_one_direction():
    data = sim.arm7(rows=(0, 1), n_demos=50, seed=0)  # each demo moves along one direction
    few = data.select_demos(data.demo_ids[:3])
    s = StateIndependentConstraint(selection="eigengap").fit(few.X, few.U).n_constraints_
    assert s == 4  # chosen silently from 3 demonstrations: q − 3
    found = D.low_rank_actions(few, few.U, s)
    assert codes(found) == ["low_rank_actions"]
    assert "each of the 3 training demonstrations" in found[0]["message"]
    many = data.select_demos(data.demo_ids[:35])
    s = StateIndependentConstraint(selection="eigengap").fit(many.X, many.U).n_constraints_
    assert s == 2 and D.low_rank_actions(many, many.U, s) == []


def test_low_rank_actions_below_the_free_directions():
    rng = np.random.default_rng(5)
    t = np.arange(2000) / 50.0
    line = np.outer(np.sin(t), [1.0, 2.0, 0.5]) * 0.05  # the finger only goes back and forth
    X = line + rng.normal(scale=1e-4, size=line.shape)
    U = local_polynomial_derivative(t, X, np.zeros(len(t), int))
    data = Demonstrations(X=X, U=U, t=t, metadata={"derivative": {"window": 9}})
    assert D.action_rank(U, D.noise_levels(data)["u_noise"]) == 1
    found = D.low_rank_actions(data, U, 1)
    assert codes(found) == ["low_rank_actions"]
    assert "span 1 direction but 2 free directions (q − s = 3 − 1)" in found[0]["message"]
    assert D.low_rank_actions(data, U, 2) == []


def test_markdown_section_and_codes():
    from ccl_cli.render.report import diagnostics_lines

    assert diagnostics_lines([])[:3] == ["## Diagnostics", "",
                                          "No warnings: the data checks found nothing to report."]
    lines = diagnostics_lines([D.warning("no_motion", "a | b")])
    assert lines[2:5] == ["| code | warning |", "|---|---|", "| `no_motion` | a / b |"]
    with pytest.raises(ValueError):
        D.warning("nothing_moved", "x")


def test_warnings_reach_stderr_json_run_json_and_the_report(tmp_path, capsys):
    """A non-moving dataset must not report "2 constraints, NPOE 0" without a word."""
    data = tmp_path / "rest.h5"
    assert main(["simulate", "arm_at_rest", "-o", str(data), "-q"]) == 0
    cfg = tmp_path / "c.yaml"
    cfg.write_text(f"data:\n  files: [{data}]\nstages: [learn-a]\n")
    capsys.readouterr()
    assert main(["run", str(cfg), "-o", str(tmp_path / "out"), "--json"]) == 0
    out, err = capsys.readouterr()
    summary = json.loads(out)
    found = {w["code"] for w in summary["warnings"]}
    assert {"no_motion", "constant_dimension", "few_demos", "low_rank_actions"} <= found
    assert all(set(w) == {"code", "message"} for w in summary["warnings"])
    assert "ccl: warning: no motion: the actions are at their noise level" in err
    assert "ccl: warning: state dimension(s) constant: finger_joint_1" in err
    run = json.loads((tmp_path / "out" / "run.json").read_text())
    assert run["warnings"] == summary["warnings"]
    report = (tmp_path / "out" / "report.md").read_text()
    assert "\n## Diagnostics\n" in report and "| `no_motion` | no motion:" in report


def test_a_clean_run_says_so_in_its_report(tmp_path, capsys):
    cfg = tmp_path / "c.yaml"
    data = tmp_path / "arm.h5"
    assert main(["simulate", "arm7", "-o", str(data), "-q"]) == 0
    cfg.write_text(f"data:\n  files: [{data}]\nstages: [learn-a]\n")
    assert main(["run", str(cfg), "-o", str(tmp_path / "out"), "--json", "-q"]) == 0
    assert json.loads(capsys.readouterr().out)["warnings"] == []
    assert "No warnings" in (tmp_path / "out" / "report.md").read_text()


def test_no_rank_false_alarm_on_samples_that_are_not_trajectories():
    # uniformly sampled states: differences in time say nothing about noise, so the rank
    # uses only the relative floor; w = Nπ spans exactly the q − s = 1 free direction
    data = sim.toy2d(sampling="uniform", n_samples=1000, n_demos=10, task=True, seed=0)
    assert not D.noise_levels(data)["temporal"]
    assert D.low_rank_actions(data, data.truth["w"], 1) == []
    assert codes(D.low_rank_actions(data, data.truth["w"], 0)) == ["low_rank_actions"]
