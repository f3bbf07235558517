"""HDF5 recordings: the canonical ``ccl-demonstrations`` layout (see :mod:`ccl_cli.io.hdf5`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.dataset import Demonstrations
from ccl_cli.errors import InputError


class Hdf5File:
    """An HDF5 recording read through the ``data`` config section."""

    def __init__(self, path: Path, data_cfg: dict[str, Any]) -> None:
        self.path = Path(path)
        self.data_cfg = data_cfg

    def load(self) -> tuple[Demonstrations, int]:
        from ccl_cli.io.hdf5 import read_demonstrations

        data, info = read_demonstrations(self.path)
        return data, info["time_origin_ns"]

    def inspect(self, gap: float | None = None) -> dict[str, Any]:
        from ccl_cli.io.hdf5 import is_canonical, read_demonstrations

        if not is_canonical(self.path):
            raise InputError(f"{self.path}: HDF5 but not a ccl-demonstrations file; convert it first")
        data, info = read_demonstrations(self.path)
        counts = np.bincount(data.demo)
        return {"samples": data.n_samples, "demos": int(data.n_demos),
                "state_names": data.state_names, "action_names": data.action_names,
                "samples_per_demo": counts.tolist(), "truth": sorted(data.truth),
                "masks": {k: len(v) for k, v in info["masks"].items()},
                "duration_s": float(sum(np.ptp(data.t[data.demo == d]) for d in data.demo_ids))}
