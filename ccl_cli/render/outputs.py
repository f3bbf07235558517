"""Writing a run's output folder from its :class:`~ccl_cli.app.run.RunResult`.

``OUTDIR/`` gets ``model.h5`` (one model) or ``models/<stage>.h5``, ``plots/*.png``,
``metrics.json``, ``report.md``, ``config.yaml`` and ``run.json``, all written into a
temporary sibling and renamed into place (:func:`ccl_cli.io.atomic.atomic_dir`), so an
interrupted or failed run leaves nothing half-written.
"""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.app.provenance import training_record
from ccl_cli.app.run import RunResult


def write_json(path: Path, value: Any) -> None:
    path.write_text(json.dumps(value, indent=2, default=_default) + "\n")  # ASCII: \\u escapes


def write_text(path: Path, text: str) -> None:
    """``text`` as UTF-8; a file name that is not UTF-8 (held as surrogate escapes,
    ``os.fsdecode``) is written back as its own bytes."""
    path.write_text(text, encoding="utf-8", errors="surrogateescape")


def _default(value: Any) -> Any:
    if isinstance(value, np.ndarray):
        return value.tolist()
    if isinstance(value, np.integer | np.floating):
        return value.item()
    return str(value)


def check_output(outdir: Path, force: bool) -> None:
    """Before any work: an existing folder ccl did not write is never replaced, and the folder
    the output goes into (or its nearest existing parent) must be writable (InputError)."""
    from ccl_cli.errors import InputError
    from ccl_cli.io.atomic import check_replaceable

    check_replaceable(outdir, force)
    parent = Path(outdir).absolute().parent
    while not parent.exists() and parent != parent.parent:
        parent = parent.parent
    if not os.access(parent, os.W_OK | os.X_OK):
        raise InputError(f"{outdir}: cannot write the output ({parent} is not writable); nothing was done")


def write_run(result: RunResult, outdir: Path, force: bool = False,
              extra_files: dict[str, Any] | None = None) -> dict[str, Any]:
    """Write every output of ``result`` into ``outdir`` atomically; returns the run's
    summary with ``outdir`` filled in. The figures are drawn by this process's drawer when
    one runs, else here (:func:`~ccl_cli.render.drawing.draw_views`). ``extra_files`` (name →
    JSON value) go into the folder too."""
    import yaml

    from ccl_cli.io.atomic import atomic_dir
    from ccl_cli.models import save_model
    from ccl_cli.render.drawing import draw_views
    from ccl_cli.render.report import markdown

    models = [r for r in result.results if r.model is not None]
    with atomic_dir(outdir, force=force) as tmp:
        for r in models:
            path = tmp / "model.h5" if len(models) == 1 else tmp / "models" / f"{r.name}.h5"
            path.parent.mkdir(exist_ok=True)
            save_model(path, r.model, training=training_record(r.name, result.cfg, result.data,
                                                               result.metrics.get(r.name)))
        plot_seconds: dict[str, float] = {}
        plots = draw_views(tmp, result.views, plot_seconds, result.cfg.spec.output.format) \
            if result.views else []
        write_json(tmp / "metrics.json", result.metrics)
        report = markdown(f"ccl {result.command}", result, plots)
        write_text(tmp / "report.md", report)
        if result.cfg.spec.output.html:  # the same text and figures as one web page
            from ccl_cli.render.html import run_page

            write_text(tmp / "report.html", run_page(f"ccl {result.command}", report, tmp, result.data,
                                                     result.views))
        write_text(tmp / "config.yaml", yaml.safe_dump(result.cfg.raw, sort_keys=False))
        write_json(tmp / "run.json", {**result.record, "plot_seconds": plot_seconds})
        for name, value in (extra_files or {}).items():
            write_json(tmp / name, value)
    return {**result.summary, "outdir": str(outdir)}


def write_evaluation(summary: dict[str, Any], out: Path, force: bool = False, fmt: str = "png") -> None:
    """``ccl evaluate -o DIR``: metrics.json, report.md (with the figures a run draws for the
    model's stage, ``plots/``) and run.json of an evaluation
    (:func:`ccl_cli.app.evaluate.evaluate_saved`'s summary), atomically."""
    from ccl_cli.app.provenance import versions
    from ccl_cli.io.atomic import atomic_dir
    from ccl_cli.render.drawing import draw_views
    from ccl_cli.render.report import metric_rows

    with atomic_dir(out, force=force) as tmp:
        plots = draw_views(tmp, summary["views"], fmt=fmt) if summary.get("views") else []
        write_json(tmp / "metrics.json", {"evaluate": summary["entry"]})
        lines = [f"# ccl evaluate: {summary['kind']} model {summary['method']} ({summary['model']})", "",
                 f"On {summary['samples']} samples in {summary['demos']} demonstrations; "
                 f"normalisers: {summary['convention']} convention (docs/metrics.md).", ""]
        lines += metric_rows({"all": summary["metrics"]}) or ["No metric: the data has no ground truth for "
                                                             "this model.", ""]
        lines += [f"![{caption}]({rel})\n" for caption, rel in plots]
        write_text(tmp / "report.md", "\n".join(lines))
        write_json(tmp / "run.json", {"command": "evaluate", "model": summary["model"],
                                      "inputs": summary["inputs"], "versions": versions()})
