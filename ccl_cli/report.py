"""Run outputs: metrics.json, report.md (tables with the plots embedded), plots/*.png
and run.json (config, package versions, timings, input hashes)."""

from __future__ import annotations

import json
import platform
import sys
from importlib import metadata
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.selection import tuning_markdown, validation_markdown

PACKAGES = ("ccl_cli", "numpy", "scipy", "h5py", "rosbags", "mcap", "mcap-ros1-support",
            "mcap-ros2-support", "typer", "pyyaml", "matplotlib")


def versions() -> dict[str, str]:
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return out


def write_json(path: Path, value: Any) -> None:
    path.write_text(json.dumps(value, indent=2, default=_default) + "\n")


def _default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer | np.floating):
        return value.item()
    return str(value)


def stage_metrics(results) -> dict[str, Any]:
    out = {}
    for r in results:
        entry = {"method": r.method, "seconds": round(r.seconds, 4), **{k: v for k, v in r.info.items()
                                                                         if k != "summary"}}
        entry.update(r.metrics)
        out[r.name] = entry
    return out


def _fmt(value: float) -> str:
    return "—" if value is None or (isinstance(value, float) and np.isnan(value)) else f"{value:.3e}"


def markdown(title: str, results_metrics: dict[str, Any], plots: list[tuple[str, str]],
             data_info: dict[str, Any]) -> str:
    lines = [f"# {title}", ""]
    lines += [f"- samples: {data_info.get('samples')} in {data_info.get('demos')} demonstrations "
              f"(train {data_info.get('train')}, test {data_info.get('test')})",
              f"- state dimension p = {data_info.get('p')}, action dimension q = {data_info.get('q')}",
              f"- inputs: {', '.join(data_info.get('files', [])) or '—'}", ""]
    lines += validation_markdown(data_info.get("validation"))
    for stage, entry in results_metrics.items():
        lines.append(f"## {stage} — {entry.get('method')}")
        lines.append("")
        if "n_constraints" in entry:
            sel = entry.get("selection") or {}
            lines.append(f"Constraints: **{entry['n_constraints']}** (rule: {sel.get('rule')}; "
                         f"{sel.get('reason', '')})")
            lines.append("")
        rows = []
        for part in ("train", "test"):
            for name, m in (entry.get(part) or {}).items():
                rows.append(f"| {part} | {name} | {_fmt(m['value'])} | {_fmt(m['error'])} | "
                            f"{_fmt(m['normaliser'])} (var of {m['normaliser_of']}) |")
        if rows:
            lines += ["| split | metric | value | error | normaliser |", "|---|---|---|---|---|", *rows, ""]
        lines += tuning_markdown(stage, entry.get("tuning"))
        lines.append(f"Time: {entry.get('seconds', 0):.3f} s")
        lines.append("")
        for caption, rel in plots:
            if caption.startswith(stage):
                lines += [f"![{caption}]({rel})", ""]
    return "\n".join(lines)


def make_plots(outdir: Path, pipeline) -> list[tuple[str, str]]:
    """2-D state and action: quiver fields; otherwise per-dimension traces over time."""
    import matplotlib

    matplotlib.use("Agg")
    import matplotlib.pyplot as plt

    plots: list[tuple[str, str]] = []
    pdir = outdir / "plots"
    pdir.mkdir(exist_ok=True)
    part = pipeline.parts()[-1][0]
    for r in pipeline.results:
        if r.model is None:
            continue
        pred, true, label, d = _prediction(r, pipeline, part, pipeline.parts()[-1][1])
        if pred is None:
            continue
        name = f"{r.name}.png"
        fig, ax = plt.subplots(figsize=(6, 5) if d.n_state == 2 and d.n_action == 2 else (8, 2 * d.n_action),
                               nrows=1 if d.n_state == 2 and d.n_action == 2 else d.n_action, squeeze=False)
        if d.n_state == 2 and d.n_action == 2:
            a = ax[0, 0]
            a.quiver(d.X[:, 0], d.X[:, 1], d.U[:, 0], d.U[:, 1], color="0.7", label="observed u",
                     angles="xy")
            if true is not None:
                a.quiver(d.X[:, 0], d.X[:, 1], true[:, 0], true[:, 1], color="tab:green",
                         label=f"true {label}", angles="xy")
            a.quiver(d.X[:, 0], d.X[:, 1], pred[:, 0], pred[:, 1], color="tab:red", label=f"learnt {label}",
                     angles="xy")
            a.set_xlabel(d.state_names[0])
            a.set_ylabel(d.state_names[1])
            a.legend(loc="best", fontsize=8)
            a.set_title(f"{r.name} ({r.method}) on {part}")
        else:
            first = d.demo == d.demo_ids[0]
            for j in range(d.n_action):
                a = ax[j, 0]
                a.plot(d.t[first], d.U[first, j], color="0.6", label="observed u")
                if true is not None:
                    a.plot(d.t[first], true[first, j], color="tab:green", label=f"true {label}")
                a.plot(d.t[first], pred[first, j], color="tab:red", ls="--", label=f"learnt {label}")
                a.set_ylabel(d.action_names[j])
            ax[0, 0].legend(loc="best", fontsize=8)
            ax[-1, 0].set_xlabel("t [s]")
            ax[0, 0].set_title(f"{r.name} ({r.method}), first {part} demonstration")
        fig.tight_layout()
        fig.savefig(pdir / name, dpi=90)
        plt.close(fig)
        plots.append((f"{r.name}: learnt vs observed{' and true' if true is not None else ''}",
                      f"plots/{name}"))
    return plots


def _prediction(r, pipeline, part: str, d: Demonstrations):
    from ccl_cli.constraint import PerDemonstration

    if r.name == "learn-v":
        return r.model.predict(d.X), d.truth.get("w"), "w", d
    if r.name == "learn-a":
        if isinstance(r.model, PerDemonstration) and part != "train":
            d = pipeline.split.train
        N = r.model.projection(d.X, d.demo)
        pi = d.truth.get("pi")
        if pi is not None and (d.has_truth("N") or d.has_truth("A")):
            return (np.einsum("nij,nj->ni", N, pi), np.einsum("nij,nj->ni", d.true_projection(), pi),
                    "N pi", d)
        return np.einsum("nij,nj->ni", N, d.U), None, "N u", d
    if r.name == "learn-pi":
        return r.model.predict(d.X), d.truth.get("pi"), "pi", d
    return None, None, "", d


def data_summary(pipeline) -> dict[str, Any]:
    d = pipeline.data
    return {"samples": d.n_samples, "demos": d.n_demos, "p": d.n_state, "q": d.n_action,
            "train": pipeline.split.train.n_samples,
            "test": pipeline.split.test.n_samples if pipeline.split.test is not None else 0,
            "files": [f["path"] for f in d.metadata.get("files", [])]}
