"""Published Denavit–Hartenberg tables of arms that ccl's users record, as chains and URDF text.

* :data:`LWR4` — KUKA LWR 4+, standard DH. Twists and link lengths (d₃ = 0.4 m, d₅ = 0.39 m)
  from Gaz, Flacco, Ficuciello, De Luca, "Dynamic identification of the KUKA LWR robot"
  (IEEE/ASME AIM 2014), Table I; their base frame sits at the shoulder, so the base-to-shoulder
  height 0.3105 m is d₁ here, and the wrist-to-flange distance 0.078 m is d₇. Joint limits
  ±170° (A1, A3, A5, A7) and ±120° (A2, A4, A6).
* :data:`PANDA` — Franka Emika Panda, modified (Craig) DH, joint limits and the flange 0.107 m
  along z₇, from the Franka Control Interface documentation ("Robot and interface
  specifications").
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ccl_cli.learn.robots.chain import Chain
from ccl_cli.learn.robots.dh import chain_urdf, dh_chain
from ccl_cli.learn.robots.transforms import translation

_DEG = np.pi / 180


@dataclass(frozen=True)
class DHRobot:
    """A DH table with its convention, joint names and limits, and a fixed tip offset along z_n."""

    name: str
    table: tuple[tuple[float, float, float, float], ...]  # [a, d, alpha, theta0] per joint
    modified: bool
    joint_names: tuple[str, ...]
    limits: tuple[tuple[float, float], ...]
    tip_z: float = 0.0
    frame: str = "flange"

    def chain(self) -> Chain:
        """The chain base → :attr:`frame`."""
        return dh_chain(self.table, modified=self.modified, names=self.joint_names, limits=self.limits,
                        tip=translation(z=self.tip_z), frame=self.frame, source=f"{self.name} DH table")

    def urdf(self) -> str:
        """URDF text of :meth:`chain` (kinematics only)."""
        return chain_urdf(self.chain(), robot=self.name)


_HALF_PI = np.pi / 2
LWR4 = DHRobot(
    name="kuka_lwr4plus",
    table=((0, 0.3105, _HALF_PI, 0), (0, 0, -_HALF_PI, 0), (0, 0.4, -_HALF_PI, 0), (0, 0, _HALF_PI, 0),
           (0, 0.39, _HALF_PI, 0), (0, 0, -_HALF_PI, 0), (0, 0.078, 0, 0)),
    modified=False,
    joint_names=tuple(f"a{i}" for i in range(1, 8)),
    limits=((-170 * _DEG, 170 * _DEG), (-120 * _DEG, 120 * _DEG)) * 3 + ((-170 * _DEG, 170 * _DEG),),
)

PANDA = DHRobot(
    name="franka_panda",
    table=((0, 0.333, 0, 0), (0, 0, -_HALF_PI, 0), (0, 0.316, _HALF_PI, 0), (0.0825, 0, _HALF_PI, 0),
           (-0.0825, 0.384, -_HALF_PI, 0), (0, 0, _HALF_PI, 0), (0.088, 0, _HALF_PI, 0)),
    modified=True,
    joint_names=tuple(f"panda_joint{i}" for i in range(1, 8)),
    limits=((-2.8973, 2.8973), (-1.7628, 1.7628), (-2.8973, 2.8973), (-3.0718, -0.0698),
            (-2.8973, 2.8973), (-0.0175, 3.7525), (-2.8973, 2.8973)),
    tip_z=0.107,
    frame="panda_link8",
)
