"""Known constraint features of a robot: Φ(q) = selected rows of its geometric Jacobian (§3.3).

``{"robot": ..., "frame": ..., "base": ..., "rows": [...]}`` names the model as a user writes it
(``robot``: a URDF / MJCF path or a DH mapping, see :func:`load_robot`); :meth:`RobotFeatures.spec`
stores the chain itself as URDF text (``{"urdf": ..., "frame": ..., "rows": ...}``), so a saved
model does not depend on the file it was learnt from.
"""

from __future__ import annotations

from collections.abc import Mapping, Sequence
from typing import Any

import numpy as np

from ccl_cli.errors import ConfigError
from ccl_cli.learn.robots.chain import Chain
from ccl_cli.learn.robots.dh import chain_urdf
from ccl_cli.learn.robots.load import load_robot
from ccl_cli.learn.robots.urdf import parse_urdf

#: Keys of a robot features mapping (``urdf`` is the stored form).
FEATURE_KEYS = ("robot", "urdf", "frame", "base", "rows")


class RobotFeatures:
    """Φ(q) = J(q)[rows] (N, r, n) for joint postures q (N, n) of ``chain``; all 6 rows
    (v_x, v_y, v_z, ω_x, ω_y, ω_z) by default."""

    def __init__(self, chain: Chain, rows: Sequence[int] | None = None) -> None:
        if rows is not None and (not len(rows) or any(not 0 <= int(r) < 6 for r in rows)):
            raise ConfigError(f"features: rows {list(rows)} must be Jacobian rows in 0..5 "
                              "(v_x, v_y, v_z, ω_x, ω_y, ω_z)")
        self.chain = chain
        self.rows = None if rows is None else [int(r) for r in rows]

    @property
    def n_joints(self) -> int:
        return self.chain.n_joints

    def __call__(self, X: np.ndarray) -> np.ndarray:
        return self.chain.jacobian(np.asarray(X, dtype=float), rows=self.rows)

    def spec(self) -> dict[str, Any]:
        """A mapping :func:`robot_features` rebuilds this from, holding the chain as URDF text."""
        return {"kind": "robot", "urdf": chain_urdf(self.chain), "frame": self.chain.frame,
                "rows": self.rows}


def robot_features(spec: Mapping[str, Any]) -> RobotFeatures:
    """:class:`RobotFeatures` from ``{robot | urdf, frame, base, rows}`` (``kind`` is ignored)."""
    keys = set(spec) - {"kind"}
    unknown = sorted(keys - set(FEATURE_KEYS))
    if unknown or ("robot" in keys) == ("urdf" in keys):
        raise ConfigError("features: a robot takes robot (a .urdf / MJCF path or {dh: ...}), frame, base, "
                          "rows"
                          + (f" (unknown: {', '.join(map(str, unknown))})" if unknown else ""))
    if "urdf" in keys:
        chain = parse_urdf(str(spec["urdf"]), spec.get("frame"), spec.get("base"), source="stored robot")
    else:
        chain = load_robot(spec["robot"], spec.get("frame"), spec.get("base"))
    return RobotFeatures(chain, spec.get("rows"))
