"""One entry point for a run spec's ``robot:`` — a URDF or MJCF path or a DH table mapping → Chain."""

from __future__ import annotations

from collections.abc import Mapping
from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn.robots.chain import Chain
from ccl_cli.learn.robots.dh import dh_chain
from ccl_cli.learn.robots.mjcf import read_mjcf
from ccl_cli.learn.robots.transforms import origin_matrix
from ccl_cli.learn.robots.urdf import read_urdf, urdf_chain
from ccl_cli.learn.robots.xmlsafe import read_xml

#: Keys of a DH mapping: ``{dh: [[a, d, alpha, theta0], ...], modified: false, types: RRRRRRR,
#: names: [...], limits: [[lo, hi], ...], tip: {xyz: [...], rpy: [...]}}``.
DH_KEYS = ("dh", "modified", "types", "names", "limits", "tip")


def load_robot(robot: str | Path | Mapping[str, Any], frame: str | None = None,
               base: str | None = None) -> Chain:
    """The chain of ``robot``: a URDF file (``frame``: a link; default the only end link; ``base``:
    default the root link), an MJCF file (``.xml`` with a ``<mujoco>`` root; ``frame``: a site or
    body; needs the ``robots`` extra), or a mapping with a DH table (keys :data:`DH_KEYS`;
    ``frame`` names the tip frame)."""
    if isinstance(robot, Mapping):
        unknown = sorted(set(robot) - set(DH_KEYS))
        if "dh" not in robot or unknown:
            raise ConfigError(f"robot: a mapping needs 'dh' and takes {', '.join(DH_KEYS)}"
                              + (f" (unknown: {', '.join(map(str, unknown))})" if unknown else ""))
        if base is not None:
            raise ConfigError("robot: base applies to a URDF; a DH table starts at its base frame")
        tip = robot.get("tip")
        if tip is not None:
            if not isinstance(tip, Mapping) or set(tip) - {"xyz", "rpy"}:
                raise ConfigError("robot: tip takes {xyz: [x, y, z], rpy: [roll, pitch, yaw]}")
            tip = origin_matrix(np.asarray(tip.get("xyz", [0, 0, 0]), float),
                                np.asarray(tip.get("rpy", [0, 0, 0]), float))
        return dh_chain(robot["dh"], modified=bool(robot.get("modified", False)), types=robot.get("types"),
                        names=robot.get("names"), limits=robot.get("limits"), tip=tip,
                        frame=frame or "tip")
    if isinstance(robot, str | Path):
        path = Path(robot)
        if path.suffix.lower() == ".urdf":
            return read_urdf(path, frame, base)
        if path.suffix.lower() in (".xml", ".mjcf"):
            root = read_xml(path)
            if root.tag == "robot":
                return urdf_chain(root, frame, base, str(path))
            if root.tag == "mujoco":
                if frame is None:
                    raise ConfigError(f"robot: {path} is MJCF; give frame: a site or body name")
                return read_mjcf(path, frame, base)
            raise InputError(f"{path}: neither URDF (<robot>) nor MJCF (<mujoco>): root element <{root.tag}>")
        raise ConfigError(f"robot: {path} — a robot model is a .urdf or MJCF .xml file or a mapping "
                          "{dh: [[a, d, alpha, theta0], ...]}")
    raise ConfigError(f"robot: expected a .urdf / .xml path or {{dh: [...]}}, got {type(robot).__name__}")
