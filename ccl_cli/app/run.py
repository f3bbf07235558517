"""Running a configured pipeline: what ``ccl run`` (and each ``ccl batch`` job) computes.

:func:`execute` reads the data, runs the stages and returns a :class:`RunResult` holding
everything the outputs are made of — the fitted models, metrics.json's content, the
summary, the provenance and the figures' data. Writing the output folder is the
renderers' job (:mod:`ccl_cli.render.outputs`); nothing here formats or draws.
"""

from __future__ import annotations

import time
from collections.abc import Callable
from dataclasses import dataclass, field
from pathlib import Path
from typing import TYPE_CHECKING, Any

from ccl_cli.app import provenance
from ccl_cli.app.views import View
from ccl_cli.config import Config
from ccl_cli.dataset import Demonstrations
from ccl_cli.learn import blas
from ccl_cli.metrics import SPLITS

if TYPE_CHECKING:
    from ccl_cli.app.stages import StageProgress


def read_data(cfg: Config, files: list[Path] | list[str] | None):
    """The dataset and its train/test masks (canonical HDF5 may carry them): ``files``, else
    the config's ``data.files`` (relative to the config's folder)."""
    from ccl_cli.io import read_dataset
    from ccl_cli.io.files import refuse_configs

    refuse_configs(files)
    return read_dataset(cfg.spec.data, files, cfg.base)


@dataclass
class RunResult:
    """A finished run: the pipeline with its stage results (models, metrics, info,
    figures' data), metrics.json's content, the summary (``--json``, batch rows) and the
    provenance record (run.json without the figures' timings)."""

    command: str
    cfg: Config
    data: Demonstrations
    pipeline: Any  # ccl_cli.app.stages.Pipeline
    metrics: dict[str, Any]
    summary: dict[str, Any]
    record: dict[str, Any]
    views: list[View] = field(default_factory=list)

    @property
    def results(self) -> list[Any]:
        return self.pipeline.results


def execute(command: str, cfg: Config, files, stages: list[tuple[str, Any]] | None = None,
            progress: StageProgress | None = None, views: bool | None = None,
            on_views: Callable[[list[View]], None] | None = None) -> RunResult:
    """Read the data, run the ``stages`` ((name, options) pairs; default: the config's
    ``stages``, shown by ``progress``) and collect the results; with ``views``
    (default: the config's ``output.plots``) also the figures' data, each stage's handed to
    ``on_views`` (if given) as soon as they are final (e.g. to draw them meanwhile)."""
    from ccl_cli.app.stages import Pipeline

    t0 = time.perf_counter()
    data, masks = read_data(cfg, files)
    data.check_finite()
    t_read = time.perf_counter() - t0
    # single-threaded BLAS (ccl_cli.learn.blas: threads cost more than they give on the run's
    # small products, and stall on shared cores); the choice goes into run.json
    with blas.threads(blas.RUN_THREADS) as blas_threads:
        stages = stages if stages is not None else cfg.stages()
        pipeline = Pipeline(cfg.spec, data, masks)
        # the parts hold their own ground truth (copies): the recording's is not read again
        # (10 columns of 10⁶ samples, 80 MB, of the tracker's; tests/test_scale.py)
        data = pipeline.data = data.without_truth()
        wanted = views if views is not None else cfg.spec.output.plots
        pipeline.run(stages, progress=progress, on_views=on_views if wanted else None)
        shown = pipeline.views() if wanted else []
    metrics = stage_metrics(pipeline.results)
    seconds = time.perf_counter() - t0
    summary = {"status": overall_status(pipeline.results), "verdict": verdict(pipeline.results),
               "command": command, "seconds": seconds, "validation": pipeline.split_info,
               "stages": summarise(metrics), "warnings": pipeline.warnings}
    record = provenance.run_record(command, cfg, data, pipeline, blas_threads,
                                   {"read": t_read} | {r.name: r.seconds for r in pipeline.results}
                                   | {"total": seconds})
    return RunResult(command, cfg, data, pipeline, metrics, summary, record, shown)


def overall_status(results) -> str:
    """The run's status: the worst of its stages' (ok < unjudged < poor < failed)."""
    order = {"ok": 0, "unjudged": 1, "poor": 2, "failed": 3}
    return max((r.status for r in results), key=order.__getitem__, default="ok")


def verdict(results) -> str:
    """One sentence: the run's status and, when a stage is not ok, what is wrong."""
    poor = [c["message"] for r in results if r.status != "ok" for c in r.checks]
    if not poor:
        held = "held-out " if any(split in r.metrics for r in results for split in SPLITS[1:]) else ""
        return f"ok: every stage's {held}evidence supports it"
    more = f" (+{len(poor) - 3} more)" if len(poor) > 3 else ""
    return f"{overall_status(results)}: " + "; ".join(poor[:3]) + more


def stage_metrics(results) -> dict[str, Any]:
    """metrics.json: per stage its method, seconds (wall and CPU), info and metrics per split."""
    out = {}
    for r in results:
        entry = {"method": r.method, "seconds": round(r.seconds, 4), "cpu_seconds": round(r.cpu_seconds, 4),
                 **{k: v for k, v in r.info.items() if k != "summary"}}
        entry.update(r.metrics)
        out[r.name] = entry
    return out


def summarise(metrics: dict[str, Any]) -> dict[str, Any]:
    """metrics.json → {stage: {method, n_constraints, train: {name: value}, test: {...},
    heldout_blocks: {...} (a model per demonstration or window), baseline: {method, train,
    test}, truth (learn-a against the file's ground truth), cone (learn-a auto: each row's
    spread over held-out folds)}} (each only where a stage has one)."""
    def one(e: dict[str, Any]) -> dict[str, Any]:
        out = {k: v for k, v in e.items() if k in ("method", "n_constraints", "status")}
        out.update({split: {m: v["value"] for m, v in e.get(split, {}).items()}
                    for split in SPLITS if split in e})
        if isinstance(e.get("baseline"), dict):
            out["baseline"] = one(e["baseline"])
        if e.get("truth"):  # learn-a against the ground truth the file carries
            out["truth"] = e["truth"]
        cone = ((e.get("selection") or {}).get("sure") or {}).get("cone")
        if cone:  # how sure: each learnt row's spread over held-out folds
            out["cone"] = cone
        return out

    return {name: one(e) for name, e in metrics.items()}


def default_outdir(command: str, cfg: Config, files=None) -> Path:
    """Where a run writes without ``-o``: ``runs/<command>-<stem>`` — the stem of the pipeline
    YAML for ``ccl run``, else of the first recording — or, when that exists, the first free
    ``…-2``, ``…-3``: a second run never refuses and never overwrites the first."""
    entries = [str(f) for f in files] if files else cfg.spec.data.files
    first = entries if isinstance(entries, str) else (entries[0] if entries else None)
    source = cfg.source if command == "run" and cfg.source != "<flags>" else first
    stem = Path(str(source)).stem if source else "data"
    base = Path("runs") / f"{command}-{stem.replace('*', '').strip('.') or 'data'}"
    candidate, n = base, 1
    while candidate.exists() or candidate.is_symlink():
        n += 1
        candidate = base.with_name(f"{base.name}-{n}")
    return candidate
