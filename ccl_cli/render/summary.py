"""The summary of a ``ccl batch``: summary.csv, summary.md, summary.json and summary.png,
one row per job, from the jobs' results (:class:`~ccl_cli.app.batch.JobResult`)."""

from __future__ import annotations

import contextlib
import csv
import json
import re
from collections.abc import Callable
from dataclasses import asdict
from pathlib import Path
from typing import Any

from ccl_cli.app.batch import JobResult
from ccl_cli.errors import OutputError
from ccl_cli.metrics import SPLITS


def _flat(res: JobResult) -> dict[str, Any]:
    row: dict[str, Any] = {"job": res.job_id, "files": ";".join(res.files), "status": res.status,
                           "seconds": round(res.seconds, 3), "error": res.error}
    methods, counts = [], []
    for stage, entry in res.stages.items():
        if entry.get("method"):
            methods.append(f"{stage}:{entry['method']}")
        if "n_constraints" in entry:
            counts.append(str(entry["n_constraints"]))
        for split in SPLITS:
            for name, value in (entry.get(split) or {}).items():
                row[f"{stage}.{split}.{name}"] = value
    row["method"] = " ".join(methods)
    row["n_constraints"] = ";".join(counts)
    return row


def write_summary(out: Path, results: list[JobResult], seconds: float, plots: bool = True) -> dict[str, Any]:
    """summary.csv, summary.md, summary.json and (``plots``: when a job draws figures)
    summary.png under ``out``, staged together: all of them replace the previous ones (a
    summary.png not drawn now is removed), or (a full disk, a file-size limit) none does and
    an :class:`~ccl_cli.errors.OutputError` says so; what the batch left empty goes too."""
    from ccl_cli.io.atomic import release_folder

    try:
        return _write_summary(out, results, seconds, plots)
    except BaseException as exc:
        release_folder(out, fault=isinstance(exc, OutputError))
        raise


def _write_summary(out: Path, results: list[JobResult], seconds: float, plots: bool) -> dict[str, Any]:
    from ccl_cli.io.atomic import atomic_path

    rows = [_flat(r) for r in results]
    fixed = ["job", "files", "method", "n_constraints", "status", "seconds", "error"]
    metric_cols = sorted({k for r in rows for k in r} - set(fixed))
    counts = {s: sum(r.status == s for r in results) for s in ("ok", "skipped", "failed")}
    lines = [f"# ccl batch — {len(results)} jobs: {counts['ok']} ran, {counts['skipped']} skipped, "
             f"{counts['failed']} failed ({seconds:.1f} s)", ""]
    shown = [c for c in metric_cols if ".test." in c] or metric_cols
    lines.append("| job | method | s | status | time [s] | " + " | ".join(shown) + " |")
    lines.append("|" + "---|" * (5 + len(shown)))
    for r in rows:
        vals = " | ".join(f"{r[c]:.3e}" if isinstance(r.get(c), float) else "—" for c in shown)
        lines.append(f"| {r['job']} | {r['method']} | {r['n_constraints']} | {r['status']} | "
                     f"{r['seconds']:.2f} | {vals} |")
    failed = [r for r in results if r.status == "failed"]
    if failed:
        lines += ["", "## Failures", ""]
        lines += [f"- `{r.job_id}` ({', '.join(r.files)}): {r.error}" for r in failed]
    summary = {"status": "ok" if not failed else "failed", "jobs": len(results), **counts,
               "seconds": seconds, "failures": [{"job": r.job_id, "files": r.files, "error": r.error}
                                                for r in failed],
               "results": [asdict(r) for r in results]}
    with contextlib.ExitStack() as staged:  # each commits when the stack closes without error
        def stage(name: str) -> Path:
            return staged.enter_context(atomic_path(out / name, force=True))

        with open(stage("summary.csv"), "w", newline="", errors="surrogateescape") as f:
            w = csv.DictWriter(f, fieldnames=fixed[:6] + metric_cols + ["error"])
            w.writeheader()
            for r in rows:
                w.writerow({k: r.get(k, "") for k in w.fieldnames})
        drawn = plots and _plot(stage, rows, shown)
        if drawn:
            lines += ["", "![metrics across jobs](summary.png)"]
        stage("summary.md").write_text("\n".join(lines) + "\n", errors="surrogateescape")
        stage("summary.json").write_text(json.dumps(summary, indent=2, default=str) + "\n")
    if not drawn:  # an earlier run's figure would show other results
        (out / "summary.png").unlink(missing_ok=True)
    return summary


def _short(name: str, width: int = 24) -> str:
    """A job name for a figure: without its key's hash suffix, cut to ``width``; a name that is
    not UTF-8 (surrogate escapes) with its undecodable bytes shown as �."""
    name = name.encode("utf-8", "surrogateescape").decode("utf-8", "replace")
    name = re.sub(r"-[0-9a-f]{8}$", "", name)
    return name if len(name) <= width else name[:width - 1] + "…"


def _plot(stage: Callable[[str], Path], rows: list[dict], columns: list[str]) -> bool:
    """summary.png (:mod:`ccl_cli.render.jobs_figure`): one row per job, one panel per metric
    (at most six) that some job has a value of, saved to ``stage("summary.png")``; False when no
    job has a value."""
    cols = [c for c in columns if any(isinstance(r.get(c), int | float) for r in rows)][:6]
    if not cols:
        return False
    from ccl_cli.render import jobs_figure

    jobs = [jobs_figure.Job(_short(r["job"], 32), r["status"], r["method"],
                            {c: float(r[c]) if isinstance(r.get(c), int | float) else None for c in cols})
            for r in rows]
    jobs_figure.write(stage("summary.png"), jobs, cols)
    return True
