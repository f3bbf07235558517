"""Every metric a stage reports, recomputed by hand from the saved models and the data.

The recomputations below use only NumPy on the saved model's predictions and the data
file (never ccl_cli.metrics or ccl_cli.app.evaluate), so a wrong normaliser, label or
formula in the reports fails here.
"""

import json
import re
from pathlib import Path

import numpy as np
import pytest
import yaml

from ccl_cli.app.stages import split_data
from ccl_cli.cli import main
from ccl_cli.config import from_mapping
from ccl_cli.io import read_demonstrations
from ccl_cli.models import load_model
from ccl_cli.render.report import STOPS

ROOT = Path(__file__).resolve().parent.parent
CONFIGS = ROOT / "configs"
SAMPLES = ROOT / "sample_data"


def tv(Y, ddof=1):
    return float(np.var(Y, axis=0, ddof=ddof).sum())


def msq(D):
    return float(np.mean(np.sum(D**2, axis=1)))


def apply(P, V):
    return np.einsum("nij,nj->ni", P, V)


def run(tmp_path, name, cfg: dict) -> tuple[dict, Path]:
    path = tmp_path / f"{name}.yaml"
    path.write_text(yaml.safe_dump(cfg))
    out = tmp_path / name
    assert main(["run", str(path), "-o", str(out), "-q"]) == 0
    return json.loads((out / "metrics.json").read_text()), out


def parts(sample: str, cfg: dict):
    data, info = read_demonstrations(SAMPLES / sample)
    split = split_data(data, from_mapping(cfg).spec, info["masks"])
    return {"train": split.train, "test": split.test}


def check(reported: dict, name: str, error: float, normaliser: float, of: str) -> None:
    m = reported[name]
    assert m["error"] == pytest.approx(error, rel=1e-9, abs=1e-15), name
    assert m["normaliser"] == pytest.approx(normaliser, rel=1e-9), name
    assert m["value"] == pytest.approx(error / normaliser, rel=1e-9), name
    assert m["normaliser_of"] == of, name


def test_learn_a_on_learnt_w_npoe_is_normalised_by_var_of_learnt_w(tmp_path):
    cfg = {"data": {"files": [str(SAMPLES / "toy2d_ncl.h5")], "test": {"fraction": 0.5, "seed": 0}},
           "stages": [{"learn-v": {"n_centres": 16}}, {"learn-a": {"method": "nhat", "on": "w"}}, "evaluate"]}
    metrics, out = run(tmp_path, "va", cfg)
    v_model, _ = load_model(out / "models" / "learn-v.h5")
    a_model, _ = load_model(out / "models" / "learn-a.h5")
    for part, d in parts("toy2d_ncl.h5", cfg).items():
        w = v_model.predict(d.X)
        # learn-v: NPE = mean ‖(uᵀw̃ / ‖w̃‖²) w̃ − w̃‖² / Σ var(u); NUPE of w and of v = u − w̃
        proj = (np.sum(d.U * w, 1) / np.sum(w * w, 1))[:, None] * w
        got = metrics["learn-v"][part]
        check(got, "NPE", msq(proj - w), tv(d.U), "u")
        check(got, "NUPE_w", msq(d.truth["w"] - w), tv(d.truth["w"]), "w")
        check(got, "NUPE_v", msq(d.truth["v"] - (d.U - w)), tv(d.truth["v"]), "v")
        # learn-a learnt from w̃: NPOE of w̃, normalised by var(w̃) and labelled so
        A = a_model.A_ / np.linalg.norm(a_model.A_, axis=1, keepdims=True)
        N_est = np.eye(2) - A.T @ A
        got = metrics["learn-a"][part]
        check(got, "NPOE", msq(w - w @ N_est.T), tv(w), "learnt w")
        N_true = d.true_projection()
        check(got, "NPPE", msq(apply(N_true, d.truth["pi"]) - d.truth["pi"] @ N_est.T), tv(d.U), "u")
        # the evaluate stage reports the very same numbers for the same models
        for stage in ("learn-v", "learn-a"):
            for name, m in metrics[stage][part].items():
                assert metrics["evaluate"][part][f"{stage}.{name}"]["value"] == m["value"]
    assert metrics["learn-a"]["on"] == "w"
    # the optimiser's stop is saved with the model, in metrics.json and (in words) in report.md
    assert v_model.stop_reason_ == metrics["learn-v"]["stop_reason"] in STOPS
    assert v_model.n_iter_ == metrics["learn-v"]["n_iter"] > 0
    assert f"Optimiser: {v_model.n_iter_} passes over the data; stopped on {STOPS[v_model.stop_reason_]}" \
        in (out / "report.md").read_text()


def test_task_term_is_not_in_npoe_and_policy_metrics_by_hand(tmp_path):
    cfg = yaml.safe_load((CONFIGS / "toy2d_learn_pi.yaml").read_text())
    cfg["data"]["files"] = [str(SAMPLES / "varying_constraint.h5")]
    metrics, out = run(tmp_path, "pi", cfg)
    a_model, _ = load_model(out / "models" / "learn-a.h5")
    pi_model, _ = load_model(out / "models" / "learn-pi.h5")
    data = parts("varying_constraint.h5", cfg)
    d = data["train"]
    # one row a and one offset b per demonstration (identity regressors): the model says
    # a·u = b, so the observation error is (a·u − b)² / ‖a‖² — the task part never counts
    a = np.empty_like(d.U)
    b = np.empty(len(d.U))
    for k, m in a_model.models_.items():
        sel = d.demo == k
        a[sel] = m.W_[0]
        b[sel] = m.Wb_[0, 0]
    norm2 = np.sum(a * a, 1)
    resid = np.sum(a * d.U, 1) - b
    check(metrics["learn-a"]["train"], "NPOE", float(np.mean(resid**2 / norm2)), tv(d.U), "u")
    assert metrics["learn-a"]["train"]["NPOE"]["value"] < 0.01  # 0.20 when A⁺b was counted
    assert "test" not in metrics["learn-a"]  # per-demonstration: no model for held-out demos
    assert {p.name for p in (out / "plots").iterdir()} == {
        "learn-a-field.png", "learn-a-selection.png", "learn-a-constraint.png", "learn-pi-field.png",
        "learn-pi-time.png"}
    report = (out / "report.md").read_text()
    assert "NMSE" not in report and "baseline" in report.lower()
    # no learn-v stage ran: no label speaks of one (the task part is learn-a's A⁺b)
    assert "Learnt from the observed actions u.\n" in report and not re.search(r"learnt v\b", report)
    assert "(var of u - learnt task part A+b)" in report
    assert metrics["learn-a"]["constraint"]["median_angle_deg"] < 1.0
    N_est = np.eye(2)[None] - a[:, :, None] * a[:, None, :] / norm2[:, None, None]
    v_est = a * (b / norm2)[:, None]
    for part, d in data.items():
        est = pi_model.predict(d.X)
        got = metrics["learn-pi"][part]
        check(got, "NUPE", msq(d.truth["pi"] - est), tv(d.truth["pi"]), "pi")
        Np = d.true_projection()
        check(got, "NCPE", msq(apply(Np, d.truth["pi"] - est)), tv(apply(Np, d.truth["pi"])), "N pi")
        if part == "train":
            z = d.U - v_est
            check(got, "NCPE_obs", msq(z - apply(N_est, est)), tv(z), "u - learnt task part A+b")
        # no policy metric compares u with π̃
        assert set(got) <= {"NUPE", "NCPE", "NCPE_obs"}
        base = metrics["learn-pi"]["baseline"][part]
        assert base["NUPE"]["value"] > got["NUPE"]["value"]


def test_original_convention_changes_the_normalisers_it_should(tmp_path):
    files = [str(SAMPLES / "two_link.h5")]
    base = {"data": {"files": files, "test": {"fraction": 0.3, "seed": 0}},
            "learn-a": {"method": "lambda", "features": "arm2"}, "stages": ["learn-a"]}
    ccl_m, _ = run(tmp_path, "ccl", base)
    orig_m, out = run(tmp_path, "orig", {**base, "metrics": {"convention": "original"}})
    model, _ = load_model(out / "model.h5")
    for part, d in parts("two_link.h5", base).items():
        N_est = model.projection(d.X)
        w = apply(d.true_projection(), d.truth["pi"])
        err_poe = msq(d.U - apply(N_est, d.U))
        err_ppe = msq(w - apply(N_est, d.truth["pi"]))
        check(ccl_m["learn-a"][part], "NPOE", err_poe, tv(d.U), "u")
        check(ccl_m["learn-a"][part], "NPPE", err_ppe, tv(d.U), "u")
        # state-dependent model: the original library divides both by var of the true w
        check(orig_m["learn-a"][part], "NPOE", err_poe, tv(w), "w")
        check(orig_m["learn-a"][part], "NPPE", err_ppe, tv(w), "w")


def test_original_convention_state_independent_and_npe(tmp_path):
    from ccl_cli.app.scoring import applied_on, constraint_metrics, nullspace_metrics
    from ccl_cli.dataset import Demonstrations
    from ccl_cli.learn.constraint import StateIndependentConstraint

    data, _ = read_demonstrations(SAMPLES / "arm7.h5")
    model = StateIndependentConstraint().fit(data.X, data.U)
    N_est = model.projection(data.X)
    applied = applied_on(model, data, data.U)
    assert applied.model is model and applied.note is None  # one A for every sample: as fitted
    ccl = constraint_metrics(applied, data, data.U, "ccl")
    orig = constraint_metrics(applied, data, data.U, "original")
    assert ccl["NPOE"]["normaliser"] == pytest.approx(tv(data.U))
    assert orig["NPOE"]["normaliser"] == pytest.approx(tv(data.truth["pi"]))  # var(π) when A is constant
    assert orig["NPPE"]["normaliser_of"] == "pi" and orig["NPOE"]["normaliser_of"] == "pi"
    assert orig["NPOE"]["error"] == pytest.approx(msq(data.U - apply(N_est, data.U)))
    # without ground truth the original normaliser cannot be had: the label says which was used
    bare = Demonstrations(data.X, data.U, demo=data.demo, t=data.t)
    label = constraint_metrics(applied_on(model, bare, bare.U), bare, bare.U, "original")["NPOE"]
    label = label["normaliser_of"]
    assert label.startswith("u (no true")
    # NPE: ddof 0 under the original convention
    w = data.U * 0.5
    assert nullspace_metrics(w, bare, "original")["NPE"]["normaliser"] == pytest.approx(tv(data.U, ddof=0))
    assert nullspace_metrics(w, bare, "ccl")["NPE"]["normaliser"] == pytest.approx(tv(data.U))


def test_evaluate_command_matches_the_stage_numbers(tmp_path, capsys):
    cfg = {"data": {"files": [str(SAMPLES / "arm7.h5")], "test": {"fraction": 0.3, "seed": 0}},
           "stages": ["learn-a"]}
    metrics, out = run(tmp_path, "arm", cfg)
    d = parts("arm7.h5", cfg)["test"]
    from ccl_cli.io import write_demonstrations

    write_demonstrations(tmp_path / "test.h5", d)
    capsys.readouterr()
    assert main(["evaluate", str(out / "model.h5"), str(tmp_path / "test.h5"), "--json"]) == 0
    ev = json.loads(capsys.readouterr().out)
    for name, m in metrics["learn-a"]["test"].items():
        assert ev["metrics"][name] == pytest.approx(m["value"], rel=1e-12)


def test_plot_helpers_subsample_and_angles():
    from ccl_cli.io.summary import activity
    from ccl_cli.metrics import subspace_angle
    from ccl_cli.render.figures import grid_subsample

    X = np.random.default_rng(0).uniform(-1, 1, (5000, 2))
    idx = grid_subsample(X, cells=10)
    assert 90 <= len(idx) <= 100  # one state per occupied cell of a 10 × 10 grid
    cells = np.floor((X[idx] + 1) / 2 * 10 - 1e-9).astype(int)
    assert len({tuple(c) for c in cells}) == len(idx)
    n1 = np.array([[0.0, 0.0, 1.0]])
    n2 = np.array([[0.0, np.sin(np.radians(5)), np.cos(np.radians(5))]])
    assert subspace_angle(n1, n2) == pytest.approx(5.0)
    assert subspace_angle(n1, -n2) == pytest.approx(5.0)  # a normal's sign does not matter
    # 500 Hz with one 2 s pause: the rate over the active time is 500 Hz, two demonstrations
    t = np.concatenate([np.arange(500), 1500 + np.arange(500)]) * 2_000_000
    act = activity(t)
    assert act["rate_hz"] == pytest.approx(500.0) and act["demos"] == 2
    assert activity(t, gap_s=3.0)["demos"] == 1


def test_a_figure_drawn_in_memory_is_the_file_save_figure_writes(tmp_path):
    """figures._draw (what ccl and its drawer run for every figure): the bytes save_figure
    writes for the same figure, and None when there is nothing to draw."""
    from ccl_cli.render.figures import _draw, save_figure, subplots

    def figure(k):
        fig, ax = subplots(figsize=(3, 2))
        ax.plot(np.arange(10) * k, label=f"line {k}")
        ax.legend(loc="upper left")
        return fig

    seconds, drawn = _draw(lambda: figure(1), "png")
    assert seconds > 0 and _draw(lambda: None, "png") is None
    save_figure(figure(1), tmp_path / "direct.png")
    assert (tmp_path / "direct.png").read_bytes() == drawn


def test_a_state_dependent_normal_is_not_called_a_plane_normal():
    from ccl_cli.render.report import constraint_lines

    info = {"names": ["dx/dt", "dy/dt", "dz/dt"], "rows": [[0.0, 0.6, 0.8]], "plane_normal": [0.0, 0.6, 0.8]}
    flat = "\n".join(constraint_lines({**info, "at": "constant"}))
    bowl = "\n".join(constraint_lines({**info, "at": "state of sample 7"}))
    assert "Plane normal: (+0.0000, +0.6000, +0.8000)." in flat and "Surface normal" not in flat
    assert "Surface normal at that state: (+0.0000, +0.6000, +0.8000)." in bowl and "Plane" not in bowl
