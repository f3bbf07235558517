"""report.md: what each stage learnt from, its metrics (docs/metrics.md), the chosen
number of constraints and why, the validation split, the diagnostics and the figures —
read from a run's results, never computed here."""

from __future__ import annotations

from typing import Any

import numpy as np

from ccl_cli.learn.defaults import N_FOLDS
from ccl_cli.metrics import SPLITS

#: Why an iterative fit stopped (``stop_reason_``), in words.
STOPS = {
    "cost": "a relative cost decrease below tol",
    "predicted": "a predicted cost decrease below tol (converged)",
    "step": "a step below tol relative to the weights",
    "gradient": "a scaled gradient below tol (converged)",
    "max_iter": "max_iter passes (not converged: raise max_iter)",
    "non-finite": "a non-finite cost",
    "budget": "the pass budget of the final stage on the original residual",
    "zero start": "a zero least-squares start (the actions are orthogonal to every feature)",
}


def _fmt(value: float) -> str:
    return "—" if value is None or (isinstance(value, float) and np.isnan(value)) else f"{value:.3e}"


HEADINGS = {"learn-v": "learn-v: null-space component w(x)", "learn-a": "learn-a: constraint A(x)",
            "learn-pi": "learn-pi: null-space policy π(x)"}
OBSERVATIONS = {"u": "the observed actions u", "w": "the null-space component w̃ learnt by learn-v"}


#: How report.md names the data a metric was computed on (metrics.json keys).
PARTS = {"heldout_blocks": f"held-out blocks inside the training demonstrations ({N_FOLDS} folds)"}


def metric_rows(entry: dict[str, Any]) -> list[str]:
    """A markdown table of an entry's metrics per split (empty list when there are none)."""
    rows = []
    for part in (*SPLITS, "all"):
        for name, m in (entry.get(part) or {}).items():
            spread = f" ± {m['se']:.1e} ({m['n_groups']} pieces)" if m.get("se") is not None else ""
            rows.append(f"| {PARTS.get(part, part)} | {name} | {_fmt(m['value'])}{spread} | "
                        f"{_fmt(m['error'])} | {_fmt(m['normaliser'])} (var of {m['normaliser_of']}) |")
    if not rows:
        return []
    return ["| data | metric | value (± SE over demonstrations or held-out blocks) | error (mean sq.) | "
            "normaliser |", "|---|---|---|---|---|", *rows, ""]


def markdown(title: str, result: Any, plots: list[tuple[str, str]]) -> str:
    """report.md of a :class:`~ccl_cli.app.run.RunResult`: the data, then per stage what was
    learnt, its metrics (docs/metrics.md) and figures (``plots``: (caption, relative path)),
    then the diagnostics."""
    results_metrics = result.metrics
    data_info = {**result.record["data"], "validation": result.record["validation"]}
    lines = [f"# {title}", "", f"**Verdict: {result.summary['verdict']}**", ""]
    lines += [f"- samples: {data_info.get('samples')} in {data_info.get('demos')} demonstrations "
              f"(train {data_info.get('train')}, test {data_info.get('test')})",
              f"- state dimension p = {data_info.get('p')}, action dimension q = {data_info.get('q')}",
              *([f"- states: {', '.join(data_info['states'])}"] if data_info.get("states") else []),
              *([f"- actions: {', '.join(data_info['actions'])}"] if data_info.get("actions") else []),
              f"- inputs: {', '.join(data_info.get('files', [])) or '—'}",
              *([f"- actions derived: {data_info['derived']}"] if data_info.get("derived") else []),
              *repair_lines(data_info.get("repairs")),
              "- metrics: mean squared error / normaliser, both shown; see docs/metrics.md", ""]
    lines += validation_markdown(data_info.get("validation"))
    for stage, entry in results_metrics.items():
        if stage == "evaluate":
            lines += [f"## evaluate: every learnt model re-scored under the {entry.get('convention')} "
                      "convention", ""]
        else:
            lines += [f"## {HEADINGS.get(stage, stage)} — method {entry.get('method')}", ""]
        if entry.get("status"):
            lines += [f"Status: **{entry['status']}**" + "".join(
                f" — {c['message']}" for c in stage_checks(result, stage)), ""]
        if "on" in entry:
            why = entry.get("on_reason")
            source = OBSERVATIONS.get(entry["on"], entry["on"])
            lines += [f"Learnt from {source}" + (f" ({why})." if why else "."), ""]
        if "n_constraints" in entry:
            sel = entry.get("selection") or {}
            lines.append(f"Constraints: **{entry['n_constraints']}** (rule: {sel.get('rule')}; "
                         f"{sel.get('reason', '')})")
            lines.append("")
        if entry.get("constraint"):
            lines += constraint_lines(entry["constraint"])
        lines += sure_lines((entry.get("selection") or {}).get("sure"), entry.get("support"))
        lines += truth_lines(entry.get("truth"))
        lines += phase_lines(entry.get("phases"))
        if entry.get("per_demo_note"):
            lines += [entry["per_demo_note"], ""]
        lines += metric_rows(entry)
        base = entry.get("baseline")
        if base:
            rows = metric_rows(base)
            lines += [f"Baseline: direct policy learning ({base.get('method')}, u regressed on β(x), "
                      "ignoring the constraints) — " + ("its own errors:" if rows else "no metric either."),
                      "", *rows]
        if entry.get("stop_reason"):
            reason = entry["stop_reason"]
            lines += [f"Optimiser: {entry.get('n_iter')} passes over the data; stopped on "
                      f"{STOPS.get(reason, reason)}.", ""]
        lines += tuning_markdown(stage, entry.get("tuning"))
        lines.append(f"Time: {entry.get('seconds', 0):.3f} s")
        lines.append("")
        for caption, rel in plots:
            if caption.split(":")[0] == stage:
                lines += [f"![{caption}]({rel})", ""]
    return "\n".join(lines) + "\n" + "\n".join(diagnostics_lines(result.record["warnings"]))


def constraint_lines(info: dict[str, Any]) -> list[str]:
    """The learnt constraint (``describe_constraint``) as markdown."""
    if "per_demo_angle_deg" in info:
        largest = max(info["per_demo_angle_deg"].values())
        return [f"Angle between each demonstration's learnt and true constraint: median "
                f"{info['median_angle_deg']:.3g}°, largest {largest:.3g}°.", ""]
    names = info["names"]
    where = "constant" if info["at"] == "constant" else f"at the {info['at']}"
    out = [f"Learnt constraint rows Ã (unit length, {where}):", "",
           "| row | " + " | ".join(names) + " |", "|---" * (len(names) + 1) + "|"]
    out += [f"| learnt {r + 1} | " + " | ".join(f"{v:+.3f}" for v in row) + " |"
            for r, row in enumerate(info["rows"])]
    out += [f"| true {r + 1} | " + " | ".join(f"{v:+.3f}" for v in row) + " |"
            for r, row in enumerate(info.get("true_rows", []))]
    out.append("")
    if "plane_normal" in info:
        angle = f"; angle to the true normal {info['angle_deg']:.3g}°" if "angle_deg" in info else ""
        kind = "Plane normal" if info["at"] == "constant" else "Surface normal at that state"
        out += [f"{kind}: (" + ", ".join(f"{v:+.4f}" for v in info["plane_normal"]) + f"){angle}.", ""]
    elif "angle_deg" in info:
        out += [f"Largest principal angle between the learnt and true row spaces: {info['angle_deg']:.3g}°.",
                ""]
    return out + stretch_lines(info)


def sure_lines(sure: dict[str, Any] | None, support: dict[str, Any] | None = None) -> list[str]:
    """"How sure": each learnt row's cone over held-out folds and the evidence for k − 1 and k + 1
    (learn-a ``auto``'s ``selection.sure``), and whether held-out evidence supports the rows."""
    if not sure and not support:
        return []
    out = ["### How sure", ""]
    if support:
        out += [("Held-out support: " if support["supported"] else "**No held-out support**: ")
                + support["why"] + ".", ""]
    cone = (sure or {}).get("cone")
    if cone:
        out += [f"Each learnt row against the rows of the same model fitted without the samples it is read "
                f"at ({cone['over']}; {cone['samples']} samples): the angle of the row from them.", "",
                "| row | median | 90th percentile |", "|---|---|---|"]
        out += [f"| {r['row']} | {r['median_deg']:.2g}° | {r['p90_deg']:.2g}° |" for r in cone["rows"]]
        out += [f"| all (largest principal angle) | {cone['median_deg']:.2g}° | {cone['p90_deg']:.2g}° |", ""]
    elif sure and sure.get("why"):
        out += [f"No cone: {sure['why']}.", ""]
    near = [e for e in (sure or {}).get("neighbours", []) if e["role"] != "chosen"]
    if near:
        out += ["Evidence for one constraint fewer and one more:", ""]
        for e in near:
            verdict = {True: "rejected", False: "not ruled out",
                       None: "not judged by the noise rule"}[e["rejected"]]
            out.append(f"- k = {e['k']} ({e['role']}): {verdict} — {e['words']}")
        out.append("")
    return out


def truth_lines(found: dict[str, Any] | None) -> list[str]:
    """The learnt constraint against the ground truth stored in the file (``entry["truth"]``)."""
    if not found:
        return []
    angle = ("no constraint in either" if found["median_deg"] is None else
             f"largest principal angle per sample median {found['median_deg']:.3g}°, 90th percentile "
             f"{found['p90_deg']:.3g}°")
    nppe = "" if found.get("NPPE") is None else f"; NPPE {found['NPPE']:.3e}"
    varies = " (the most common; it varies over the samples)" if found["true_k_varies"] else ""
    out = ["### Against the ground truth in the file", "",
           f"On the {found['part']} data ({found['samples']} samples"
           + (f"; angles read at {found['read_at']} of them, evenly spaced" if found.get("read_at") else "")
           + f"): true k = {found['true_k']}{varies}, "
           f"learnt k = {found['learnt_k']} ({100 * found['k_agrees']:.0f} % of the samples with as many "
           f"learnt as true rows); {angle}{nppe}.", ""]
    if found["far"]:
        out += [f"**Far off**: {found['why']}.", ""]
    return out


def phase_lines(found: dict[str, Any] | None) -> list[str]:
    """Where a constraint that holds in stretches holds (``entry["phases"]``), per demonstration."""
    if not found:
        return []
    out = ["### Phases", "", f"The constraint holds in {100 * found['share']:.0f} % of the training samples "
           "and nowhere else (free motion):", "", "| demo | held (s) | of (s) | where (s from its start) |",
           "|---|---|---|---|"]
    for d in found["demos"]:
        spans = ", ".join(f"{a:.1f}–{b:.1f}" for a, b in d["spans"][:6]) + (
            f", … ({len(d['spans']) - 6} more)" if len(d["spans"]) > 6 else "")
        out.append(f"| {d['demo']} | {d['held_s']:.1f} | {d['duration_s']:.1f} | {spans or '—'} |")
    return [*out, ""]


def stretch_lines(info: dict[str, Any]) -> list[str]:
    """The first row of each window / segment of a per-stretch model (``describe_constraint``'s
    ``stretches``) as a markdown table."""
    found = info.get("stretches")
    if not found or not found["shown"]:
        return []
    shown, names = found["shown"], info["names"]
    truth = all("angle_deg" in s for s in shown)
    more = f" (the first {len(shown)} of {found['count']})" if found["count"] > len(shown) else ""
    out = [f"Row 1 of each {info.get('per', 'stretch')}{more}:", "",
           "| demo | from (s) | to (s) | " + " | ".join(names) + (" | angle to truth |" if truth else " |"),
           "|---" * (len(names) + 3 + truth) + "|"]
    for s in shown:
        cells = [str(s["demo"]), f"{s['start_s']:.1f}", f"{s['end_s']:.1f}", *(f"{v:+.3f}" for v in s["row"])]
        if truth:
            cells.append(f"{s['angle_deg']:.2f}°")
        out.append("| " + " | ".join(cells) + " |")
    return [*out, ""]


# -- sections of report.md ------------------------------------------------------------------
def repair_lines(repairs: list[dict[str, Any]] | None) -> list[str]:
    """report.md's lines on what the sensor-fault repair did, per demonstration (times from its
    first sample); none when it did nothing."""
    if not repairs:
        return []
    said = [f"demonstration {r['demo']}: {r['samples']} {r['action']} ({r['fault'].replace('_', ' ')}) at "
            + ", ".join(f"{a:.2f}–{b:.2f} s" if b > a else f"{a:.2f} s" for a, b in r["times"][:4])
            + (f" and {len(r['times']) - 4} more" if len(r["times"]) > 4 else "") for r in repairs[:8]]
    more = [f"  - and {len(repairs) - 8} more (run.json: data.repairs)"] if len(repairs) > 8 else []
    return ["- sensor-fault repair (samples as read; the rest kept as recorded):",
            *(f"  - {x}" for x in said), *more]


def validation_markdown(split_info: dict[str, Any] | None) -> list[str]:
    """The "Validation" section of report.md: how train and test were split, and why."""
    if not split_info:
        return []
    lines = ["## Validation", "", f"Split: **{split_info.get('kind')}** — {split_info.get('reason')}", ""]
    unit = "demos" if split_info.get("kind") == "demonstrations" else "blocks"
    if split_info.get("kind") in ("demonstrations", "blocks"):
        lines += [f"| | {unit} | samples |", "|---|---|---|"]
        for part in ("train", "test"):
            lines.append(f"| {part} | {split_info.get(f'n_{part}_{unit}', '—')} | "
                         f"{split_info.get(f'n_{part}_samples')} |")
        if split_info.get("n_dropped_samples"):
            lines.append(f"| guard gaps (dropped) | | {split_info['n_dropped_samples']} |")
        lines.append("")
    return lines


def tuning_markdown(stage: str, tuning: dict[str, Any] | None) -> list[str]:
    """Table of the cross-validation curve of one stage's hyperparameter search."""
    if not tuning:
        return []
    if tuning.get("chosen") is None:
        return [f"### {stage}: hyperparameters", "", tuning.get("reason", "not tuned"), ""]
    lines = [f"### {stage}: hyperparameters by cross-validation", "",
             f"Chosen: {tuning['chosen']} ({tuning['rule']}; {tuning['folds']['reason']}; "
             f"{tuning['budget_used']} of a budget of {tuning['budget']} {tuning.get('budget_unit', 'fits')}"
             + (f", {tuning['skipped']} candidates skipped" if tuning.get("skipped") else "") + ")", "",
             *([tuning["subset"][0].upper() + tuning["subset"][1:] + "; the chosen setting was then "
                "fitted on all of them.", ""] if tuning.get("subset") else []),
             *([f"Held-out errors on the {tuning['scored_on']}.", ""] if tuning.get("scored_on") else []),
             "| candidate | held-out error | SE |", "|---|---|---|"]
    for r in tuning["scores"]:
        mark = " **←**" if r["params"] == tuning["chosen"] else ""
        lines.append(f"| {r['params']}{mark} | {r['mean']:.3e} | {r['se']:.1e} |")
    return [*lines, ""]


def diagnostics_lines(warnings: list[dict[str, str]]) -> list[str]:
    """The "Diagnostics" section of report.md: one line per warning, or that none fired."""
    lines = ["## Diagnostics", ""]
    if not warnings:
        return [*lines, "No warnings: the data checks found nothing to report.", ""]
    lines += ["| code | warning |", "|---|---|"]
    lines += [f"| `{w['code']}` | {w['message'].replace('|', '/')} |" for w in warnings]
    return [*lines, ""]


def stage_checks(result: Any, stage: str) -> list[dict[str, str]]:
    """The verdict checks that fired for ``stage``."""
    return [c for r in result.results if r.name == stage for c in r.checks]
