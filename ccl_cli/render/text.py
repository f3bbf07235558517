"""The command line's text: run summaries on stderr, ``--json`` lines, ``ccl inspect``'s listing."""

from __future__ import annotations

import json
from typing import Any

from ccl_cli.metrics import SPLITS


def json_line(summary: dict[str, Any]) -> str:
    """One machine-readable object on one line (``--json``)."""
    return json.dumps(summary, default=str) + "\n"


def summary_lines(summary: dict[str, Any], quiet: bool = False) -> list[str]:
    """A run's summary for stderr: the verdict, the validation split, one line per stage (and
    baseline) with its status, constraint count and metrics, where the outputs went; nothing
    with ``quiet``."""
    if quiet:  # -q: nothing but warnings and errors (the checks behind a poor verdict are warnings)
        return []
    out = []
    if summary.get("verdict"):
        out.append(f"verdict: {summary['verdict']}")
    val = summary.get("validation")
    if val:
        out.append(f"validation: {val.get('kind')} ({val.get('reason')})")

    def line(label: str, entry: dict[str, Any]) -> str:
        parts = [label] + ([entry["status"]] if entry.get("status") else [])
        if "n_constraints" in entry:
            parts.append(f"s={entry['n_constraints']}")
        for split in SPLITS:
            for name, value in (entry.get(split) or {}).items():
                parts.append(f"{split.replace('heldout_blocks', 'held-out blocks')} {name}={value:.3e}")
        return "  ".join(parts)

    for stage, entry in (summary.get("stages") or {}).items():
        out.append(line(f"{stage} ({entry.get('method')})", entry))
        if entry.get("baseline"):
            out.append(line(f"{stage} baseline ({entry['baseline'].get('method')})", entry["baseline"]))
    if summary.get("outdir"):
        out.append(f"outputs in {summary['outdir']}")
    return out


def model_lines(info: dict[str, Any]) -> list[str]:
    """``ccl inspect MODEL.h5``: what the model is and what it was trained on."""
    out = [f"path:     {info['path']}", f"format:   ccl model (schema {info['schema_version']})",
           f"model:    {info['kind']}, method {info['method']}"
           + (f", {len(info['demonstrations'])} demonstrations" if info.get("demonstrations") else "")]
    if "n_constraints" in info:
        sel = info.get("selection") or {}
        why = f" (rule {sel.get('rule')}: {sel.get('reason')})" if sel.get("rule") else ""
        out.append(f"constraints: {info['n_constraints']}{why}")
        out += sure_lines(sel.get("sure"))
    dims = f"state p = {info.get('n_features_in')}" if info.get("n_features_in") else "state p not recorded"
    out.append(f"dimensions: {dims}, action q = {info.get('n_action')}")
    if info.get("basis"):
        b = info["basis"]
        rbf = f"{b['n_centres']} normalised RBFs, σ² = {b['sigma2']:.4g}" if b["kind"] == "rbf" else ""
        out.append("basis:    " + (rbf or "linear [x; 1]"))
    training = info.get("training") or {}
    if training.get("stage"):
        out.append(f"trained:  stage {training['stage']}")
    for path, digest in (training.get("inputs") or {}).items():
        out.append(f"  input   {path}  sha256 {digest[:16]}…")
    for r in (training.get("repairs") or [])[:8]:
        out.append(f"  repaired demonstration {r['demo']}: {r['samples']} sample(s) {r['action']} "
                   f"({r['fault']})")
    for part, figures in (training.get("metrics") or {}).items():
        out.append(f"  {part:7s} " + "  ".join(f"{k}={v:.3e}" for k, v in figures.items()
                                               if isinstance(v, float)))
    if training.get("config"):
        import json

        out.append(f"config:   {json.dumps(training['config'], default=str)[:300]}")
    return out


def sure_lines(sure: dict[str, Any] | None) -> list[str]:
    """How sure learn-a's ``auto`` was (``selection.sure``): each learnt row's cone over held-out
    folds, and the evidence for one constraint fewer and one more."""
    if not sure:
        return []
    out = []
    cone = sure.get("cone")
    if cone:
        rows = ", ".join(f"row {r['row']} {r['median_deg']:.2g}° (90 %: {r['p90_deg']:.2g}°)"
                         for r in cone["rows"])
        out.append(f"cone:     {rows} from the rows fitted without them ({cone['over']})")
    for e in sure.get("neighbours") or []:
        if e["role"] != "chosen":
            verdict = {True: "rejected", False: "not ruled out", None: "not judged"}[e["rejected"]]
            out.append(f"k = {e['k']}:    {verdict}: {e['words']}")
    return out


def utc(ns: int) -> str:
    """A log time (int ns since the Unix epoch) as an ISO date in UTC, to the millisecond;
    a stamp before 1980 is a time since boot or a simulation clock, shown as seconds."""
    if ns < 315_532_800 * 10**9:
        return f"{ns / 1e9:.3f} s (a clock that is not a date: time since boot or simulation time)"
    from datetime import UTC, datetime

    seconds, rest = divmod(int(ns), 10**9)
    stamp = datetime.fromtimestamp(seconds, tz=UTC)
    return stamp.strftime("%Y-%m-%d %H:%M:%S") + f".{rest // 10**6:03d} UTC"


def inspect_lines(info: dict[str, Any]) -> list[str]:
    """``ccl inspect``'s text rendering (one function, so every format's listing shows here)."""
    if info.get("format") == "ccl-model":
        return model_lines(info)
    out = [f"path:     {info['path']}", f"format:   {info['format']}  ({info['size_bytes']} bytes)"]
    if "duration_s" in info:
        span = "summed over demonstrations" if info["format"] == "hdf5" else "first to last message"
        out.append(f"duration: {info['duration_s']:.3f} s ({span})")
    if info.get("start_ns") is not None and info.get("end_ns") is not None:
        out.append(f"start:    {utc(info['start_ns'])}")
        out.append(f"end:      {utc(info['end_ns'])}")
    for key in ("storage", "compression", "encoding"):
        if info.get(key):
            out.append(f"{key + ':':9s} {info[key]}")
    for topic, t in (info.get("topics") or {}).items():
        rate = f"{t['rate_hz']:.1f} Hz" if t.get("rate_hz") else "-"
        out.append(f"  {topic:30s} {t['type']:36s} {t['count']:>9d} msgs  {rate:>10s}"
                   + (f" over {t['active_s']:.2f} s active" if t.get("active_s") else ""))
        if t.get("fields"):
            out.append(f"  {'':30s} fields: {', '.join(t['fields'])}")
        if t.get("joint_names"):
            out.append(f"  {'':30s} joints: {', '.join(t['joint_names'])}")
    if "columns" in info:
        headless = "" if info.get("header", True) else " (no header: columns by 0-based index)"
        out.append(f"columns:  {', '.join(map(str, info['columns']))}{headless}")
        if info.get("text_columns"):
            out.append(f"text:     {', '.join(info['text_columns'])} (text, not numbers: never a state or "
                       "an action)")
        if info.get("empty_columns"):
            out.append(f"empty:    {', '.join(info['empty_columns'])}")
        rate = f", {info['rate_hz']:.1f} Hz over {info['active_s']:.2f} s active" \
            if info.get("rate_hz") else ""
        timed = f"time column {info['time_column']}{rate}" if info.get("time_column") else "no time column"
        out.append(f"rows:     {info['rows']} ({timed})")
    if info.get("repeats"):
        r = info["repeats"]
        cols = ", ".join(map(str, r["columns"][:6])) + (", …" if len(r["columns"]) > 6 else "")
        out.append(f"repeats:  {r['rows']} rows repeat the row before (in {cols}): the sensor updates at "
                   f"{r['rate_hz']:.1f} Hz, a pose every {r['per_pose']:.3g} rows; learning keeps each "
                   "pose's first row (data.faults: {stamps: keep} keeps every row)")
    if info.get("needs"):
        out.append("to read it, a config (-c) says:")
        out += [f"  {need}" for need in info["needs"]]
    for node in info.get("tree", []):  # HDF5 / .mat contents
        value = f"  = {node['value']:g} (one number: time: {{variable: {node['path']}}} takes it as the " \
            "sampling interval)" if "value" in node else ""
        out.append("  " + "  ".join(str(v) for k, v in node.items() if k not in ("names", "value")) + value)
    if "gap_s" in info and "demos" in info:
        out.append(f"pauses:   {info['demos']} stretches in {info.get('demos_from')} between pauses > "
                   f"{info['gap_s']:.3g} s ({info.get('gap_rule')}; change with --gap)")
    if "as_configured" in info:
        c = info["as_configured"]
        each = c["samples_per_demo"]
        shown = ", ".join(map(str, each[:8])) + (", …" if len(each) > 8 else "")
        out.append(f"learning reads: {c['demos']} demonstration(s), {c['samples']} samples ({shown}), "
                   f"{c['duration_s']:.2f} s; {c['split']}")
        out.append(f"  state {', '.join(c['state_names'])}; action {', '.join(c['action_names'])}")
        for r in c.get("repairs") or []:
            times = ", ".join(f"{a:.2f}–{b:.2f} s" if b > a else f"{a:.2f} s" for a, b in r["times"][:6])
            more = f" and {len(r['times']) - 6} more" if len(r["times"]) > 6 else ""
            out.append(f"  repaired: demonstration {r['demo']}: {r['samples']} sample(s) {r['action']} "
                       f"({r['fault']}) at {times}{more}")
    for key in ("samples", "demos", "samples_per_demo", "state_names", "action_names", "truth", "masks"):
        if key in info and not (key == "demos" and "gap_s" in info):
            out.append(f"{key + ':':9s} {info[key]}")
    return out
