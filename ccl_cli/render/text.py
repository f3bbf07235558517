"""The command line's text: run summaries on stderr, ``--json`` lines, ``ccl inspect``'s listing."""

from __future__ import annotations

import json
from typing import Any


def json_line(summary: dict[str, Any]) -> str:
    """One machine-readable object on one line (``--json``)."""
    return json.dumps(summary, default=str) + "\n"


def summary_lines(summary: dict[str, Any], quiet: bool = False) -> list[str]:
    """A run's summary for stderr: the validation split, one line per stage (and baseline)
    with its constraint count and metrics, where the outputs went. With ``quiet`` only a
    held-out set of time blocks is stated (a choice the user must know about, like a warning)."""
    out = []
    if summary.get("verdict") and (not quiet or summary.get("status") != "ok"):
        out.append(f"verdict: {summary['verdict']}")
    val = summary.get("validation")
    if val and (not quiet or val.get("kind") == "blocks"):
        out.append(f"validation: {val.get('kind')} ({val.get('reason')})")
    if quiet:
        return out

    def line(label: str, entry: dict[str, Any]) -> str:
        parts = [label] + ([entry["status"]] if entry.get("status") else [])
        if "n_constraints" in entry:
            parts.append(f"s={entry['n_constraints']}")
        for split in ("train", "test"):
            for name, value in (entry.get(split) or {}).items():
                parts.append(f"{split} {name}={value:.3e}")
        return "  ".join(parts)

    for stage, entry in (summary.get("stages") or {}).items():
        out.append(line(f"{stage} ({entry.get('method')})", entry))
        if entry.get("baseline"):
            out.append(line(f"{stage} baseline ({entry['baseline'].get('method')})", entry["baseline"]))
    if summary.get("outdir"):
        out.append(f"outputs in {summary['outdir']}")
    return out


def inspect_lines(info: dict[str, Any]) -> list[str]:
    """``ccl inspect``'s text rendering (one function, so every format's listing shows here)."""
    out = [f"path:     {info['path']}", f"format:   {info['format']}  ({info['size_bytes']} bytes)"]
    if "duration_s" in info:
        span = "summed over demonstrations" if info["format"] == "hdf5" else "first to last message"
        out.append(f"duration: {info['duration_s']:.3f} s ({span})")
    for topic, t in (info.get("topics") or {}).items():
        rate = f"{t['rate_hz']:.1f} Hz" if t.get("rate_hz") else "-"
        out.append(f"  {topic:30s} {t['type']:36s} {t['count']:>9d} msgs  {rate:>10s}"
                   + (f" over {t['active_s']:.2f} s active" if t.get("active_s") else ""))
        if t.get("fields"):
            out.append(f"  {'':30s} fields: {', '.join(t['fields'])}")
        if t.get("joint_names"):
            out.append(f"  {'':30s} joints: {', '.join(t['joint_names'])}")
    if "columns" in info:
        out.append(f"columns:  {', '.join(map(str, info['columns']))}")
        rate = f", {info['rate_hz']:.1f} Hz over {info['active_s']:.2f} s active" \
            if info.get("rate_hz") else ""
        out.append(f"rows:     {info['rows']} (time column {info['time_column']}{rate})")
    for node in info.get("tree", []):  # HDF5 / .mat contents
        out.append("  " + "  ".join(str(v) for k, v in node.items() if k != "names"))
    if "gap_s" in info and "demos" in info:
        out.append(f"demos:    {info['demos']} in {info.get('demos_from')} (split on pauses > "
                   f"{info['gap_s']:.3g} s: {info.get('gap_rule')}; change with --gap)")
    for key in ("samples", "demos", "samples_per_demo", "state_names", "action_names", "truth", "masks"):
        if key in info and not (key == "demos" and "gap_s" in info):
            out.append(f"{key + ':':9s} {info[key]}")
    return out
