"""Running a configured pipeline into an output folder: what ``ccl run`` (and each
``ccl batch`` job) does, as a library function returning a summary."""

from __future__ import annotations

import os
import sys
import time
from collections.abc import Callable
from pathlib import Path
from typing import Any

from ccl_cli.config import Config, stage_entry
from ccl_cli.errors import ConfigError
from ccl_cli.learn import blas


def read_data(cfg: Config, files: list[Path] | list[str] | None):
    """The dataset and its train/test masks (canonical HDF5 may carry them)."""
    from ccl_cli.io import read_dataset

    return read_dataset(cfg.get("data"), files, cfg.base)


def default_outdir(command: str, cfg: Config) -> Path:
    stem = Path(cfg.source.split(" + ")[0]).stem if command == "run" and cfg.source != "<flags>" else command
    return Path("runs") / stem


def run_to_dir(command: str, cfg: Config, files, outdir: Path, force: bool = False,
               stages: list[tuple[str, dict]] | None = None,
               progress: Callable[[], None] | None = None,
               extra_files: dict[str, Any] | None = None,
               plot_workers: int | None = None) -> dict[str, Any]:
    """Read the data, run the stages, write every output into ``outdir`` atomically.

    The figures are drawn by ``plot_workers`` processes (default: 2 on a machine with two
    or more cores; ``ccl batch`` passes 1, its jobs already fill the cores).

    Returns the summary (status, outdir, per-stage method, constraint count and metric values).
    ``extra_files`` (name → JSON value) are written into the folder with the rest.
    """
    from ccl_cli.app.stages import Pipeline, stage_list
    from ccl_cli.diagnostics import markdown_section
    from ccl_cli.io.atomic import atomic_dir, check_replaceable
    from ccl_cli.models import save_model
    from ccl_cli.render.report import data_summary, make_plots, markdown, stage_metrics, versions, write_json

    t0 = time.perf_counter()
    check_replaceable(outdir, force)  # before any work: a folder ccl did not write is never replaced
    data, masks = read_data(cfg, files)
    data.check_finite()
    t_read = time.perf_counter() - t0
    # small problems run single-threaded BLAS (ccl_cli.learn.blas: threads cost more than they
    # give there, and stall on shared cores); the choice goes into run.json
    with blas.threads(blas.stage_threads(data.n_samples)) as blas_threads:
        stages = stages if stages is not None else stage_list(cfg)
        pipeline = Pipeline(cfg, data, masks)
        pipeline.run(stages, progress=progress)
        metrics = stage_metrics(pipeline.results)
        hashes = {f["path"]: f["sha256"] for f in data.metadata.get("files", [])}
        with atomic_dir(outdir, force=force) as tmp:
            single = len([r for r in pipeline.results if r.model is not None]) == 1
            for r in pipeline.results:
                if r.model is None:
                    continue
                path = tmp / "model.h5" if single else tmp / "models" / f"{r.name}.h5"
                path.parent.mkdir(exist_ok=True)
                save_model(path, r.model, training={"stage": r.name, "config": dict(cfg), "inputs": hashes,
                                                    "versions": versions()})
            plot_seconds: dict[str, float] = {}
            if plot_workers is None:
                plot_workers = 2 if (os.cpu_count() or 1) >= 2 else 1
            plots = make_plots(tmp, pipeline, plot_seconds, plot_workers) \
                if (cfg.get("output") or {}).get("plots", True) else []
            write_json(tmp / "metrics.json", metrics)
            summary = {**data_summary(pipeline), "validation": pipeline.split_info}
            (tmp / "report.md").write_text(markdown(f"ccl {command}", metrics, plots, summary)
                                           + "\n" + "\n".join(markdown_section(pipeline.warnings)))
            import yaml

            (tmp / "config.yaml").write_text(yaml.safe_dump(dict(cfg), sort_keys=False))
            write_json(tmp / "run.json", {
                "command": command, "argv": sys.argv, "config": dict(cfg), "config_source": cfg.source,
                "inputs": hashes, "versions": versions(),
                "timings": {"read": t_read} | {r.name: r.seconds for r in pipeline.results}
                | {"total": time.perf_counter() - t0},
                "data": data_summary(pipeline), "validation": pipeline.split_info,
                "warnings": pipeline.warnings, "plot_seconds": plot_seconds,
                "blas": {"threads": blas_threads, "rule": f"1 below {blas.SMALL_SAMPLES} samples, else the "
                         "library's own count (None: a BLAS ccl cannot control)"},
            })
            for name, value in (extra_files or {}).items():
                write_json(tmp / name, value)
        return {"status": "ok", "command": command, "outdir": str(outdir),
                "seconds": time.perf_counter() - t0, "validation": pipeline.split_info,
                "stages": summarise(metrics), "warnings": pipeline.warnings}


def summarise(metrics: dict[str, Any]) -> dict[str, Any]:
    """metrics.json → {stage: {method, n_constraints, train: {name: value}, test: {...},
    baseline: {method, train, test}}} (the baseline only where a stage has one)."""
    def one(e: dict[str, Any]) -> dict[str, Any]:
        out = {k: v for k, v in e.items() if k in ("method", "n_constraints")}
        out.update({split: {m: v["value"] for m, v in e.get(split, {}).items()}
                    for split in ("train", "test") if split in e})
        if isinstance(e.get("baseline"), dict):
            out["baseline"] = one(e["baseline"])
        return out

    return {name: one(e) for name, e in metrics.items()}


def stage_list(cfg: Config, default: list[str] | None = None) -> list[tuple[str, dict]]:
    """The config's stages as (name, options) pairs (``default`` names when it has none)."""
    items = cfg.get("stages")
    if not items:
        if default is None:
            raise ConfigError(f"{cfg.source}: no stages to run (add a stages: list)")
        return [(name, {}) for name in default]
    return [stage_entry(item, cfg, i) for i, item in enumerate(items)]
