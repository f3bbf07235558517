"""What a run records next to its outputs: the config, the inputs' hashes, the package
versions, the timings, the data and how it was split — run.json's content."""

from __future__ import annotations

import functools
import platform
import sys
from importlib import metadata
from typing import Any

from ccl_cli.dataset import Demonstrations
from ccl_cli.io.summary import repairs
from ccl_cli.learn import blas

PACKAGES = ("ccl_cli", "numpy", "scipy", "h5py", "rosbags", "mcap", "mcap-ros1-support",
            "mcap-ros2-support", "typer", "pyyaml", "matplotlib")


@functools.cache
def _versions() -> tuple[tuple[str, str], ...]:
    out = {"python": sys.version.split()[0], "platform": platform.platform()}
    for name in PACKAGES:
        try:
            out[name] = metadata.version(name)
        except metadata.PackageNotFoundError:
            out[name] = "not installed"
    return tuple(out.items())


def versions() -> dict[str, str]:
    """Python, platform and package versions (computed once per process)."""
    return dict(_versions())


def input_hashes(data: Demonstrations) -> dict[str, str]:
    """sha256 of every input file the data came from: path → hex digest."""
    return {f["path"]: f["sha256"] for f in data.metadata.get("files", [])}


def derived_actions(meta: dict[str, Any]) -> str | None:
    """How the readers derived the actions from the states (window, order and why), one
    phrase per distinct setting; None when the actions were read as recorded."""
    seen = []
    for f in meta.get("files", []):
        a = f.get("action") if isinstance(f, dict) else None
        if isinstance(a, dict) and a.get("derived"):
            text = (f"derived from the states ({a['derived']}, order {a.get('order')}, window "
                    f"{a.get('window')} samples: {a.get('window_rule', 'configured')})")
            if text not in seen:
                seen.append(text)
    return "; ".join(seen) or None


def named(names: list[str], units: list[str]) -> list[str]:
    """``name [unit]`` per dimension (``name`` alone where the unit is unknown)."""
    return [f"{n} [{u}]" if u else n for n, u in zip(names, units, strict=True)]


def data_summary(pipeline: Any) -> dict[str, Any]:
    """Sizes of the data and of its train/test parts, the input files, how actions were made,
    what the sensor-fault repair did per demonstration (:func:`ccl_cli.io.summary.repairs`)."""
    d = pipeline.data
    return {"samples": d.n_samples, "demos": d.n_demos, "p": d.n_state, "q": d.n_action,
            "states": named(d.state_names, d.state_units), "actions": named(d.action_names, d.action_units),
            "train": pipeline.split.train.n_samples,
            "test": pipeline.split.test.n_samples if pipeline.split.test is not None else 0,
            "files": [f["path"] for f in d.metadata.get("files", [])],
            "derived": derived_actions(d.metadata), "repairs": repairs(d)}


def run_record(command: str, cfg: Any, data: Demonstrations, pipeline: Any, blas_threads: int | None,
               timings: dict[str, float]) -> dict[str, Any]:
    """run.json: command, argv, config, inputs' sha256, versions, timings, data, validation,
    warnings and the BLAS threads used."""
    return {
        "command": command, "argv": sys.argv, "config": cfg.raw, "config_source": cfg.source,
        "inputs": input_hashes(data), "versions": versions(), "timings": timings,
        "data": data_summary(pipeline), "validation": pipeline.split_info, "warnings": pipeline.warnings,
        "blas": {"threads": blas_threads,
                 "rule": f"{blas.RUN_THREADS} at any size: the run's products are too small to share "
                 "(None: a BLAS ccl cannot control)"},
    }


def frame_of(meta: dict[str, Any]) -> dict[str, Any] | None:
    """The frame the states are expressed in, when the readers computed them by forward
    kinematics ({robot, base, frame}: the chain's ``frame`` seen from its ``base``); None when the
    states are the recording's own coordinates."""
    for f in meta.get("files", []):
        fk = f.get("forward_kinematics") if isinstance(f, dict) else None
        if isinstance(fk, dict):
            return {k: fk.get(k) for k in ("robot", "base", "frame")}
    return None


def training_record(stage: str, cfg: Any, data: Demonstrations, metrics: dict[str, Any] | None = None
                    ) -> dict[str, Any]:
    """What a saved model records of its training: stage, config, input hashes, versions, its
    figures ({train|test: {metric: value}} from metrics.json's stage entry), what the data's
    columns are (names, units and frame, for ``ccl export``) and what the sensor-fault repair
    did to the data it read, per demonstration (``repairs``)."""
    figures = {part: {name: m["value"] for name, m in (metrics or {}).get(part, {}).items()}
               for part in ("train", "test") if part in (metrics or {})}
    columns = {"states": data.state_names, "state_units": data.state_units, "actions": data.action_names,
               "action_units": data.action_units, "frame": frame_of(data.metadata)}
    return {"stage": stage, "config": cfg.raw, "inputs": input_hashes(data), "versions": versions(),
            "metrics": figures, "data": columns, "repairs": repairs(data)}
