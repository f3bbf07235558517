"""Arm models of the reference problems (ALGORITHMS.md §7), batched over postures.

* :class:`TwoLinkArm` — planar, link lengths (1, 1).
* :class:`SevenDofArm` — the DLR/KUKA chain of the original wiping demonstration,
  standard Denavit–Hartenberg with d = 0, a = (0, 0.3, 0.4, 0.5, 0.39, 0, 0.2) m,
  α = (π/2, −π/2, −π/2, π/2, π/2, −π/2, 0); geometric Jacobian from the DH frames.
"""

from __future__ import annotations

from typing import get_args

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.params import ArmName


class TwoLinkArm:
    """Planar 2-link arm; joint angles Q (N, 2) in radians."""

    name = "arm2"
    n_joints = 2

    def __init__(self, lengths: tuple[float, float] = (1.0, 1.0)) -> None:
        self.lengths = lengths

    def forward(self, Q: np.ndarray) -> np.ndarray:
        """End-effector position (N, 2)."""
        l1, l2 = self.lengths
        q1, q12 = Q[:, 0], Q[:, 0] + Q[:, 1]
        return np.stack([l1 * np.cos(q1) + l2 * np.cos(q12), l1 * np.sin(q1) + l2 * np.sin(q12)], 1)

    def jacobian(self, Q: np.ndarray) -> np.ndarray:
        """∂x_ee/∂q (N, 2, 2)."""
        l1, l2 = self.lengths
        q1, q12 = Q[:, 0], Q[:, 0] + Q[:, 1]
        J = np.empty((Q.shape[0], 2, 2))
        J[:, 0, 0] = -l1 * np.sin(q1) - l2 * np.sin(q12)
        J[:, 0, 1] = -l2 * np.sin(q12)
        J[:, 1, 0] = l1 * np.cos(q1) + l2 * np.cos(q12)
        J[:, 1, 1] = l2 * np.cos(q12)
        return J


class SevenDofArm:
    """7-DoF revolute chain in standard DH; joint angles Q (N, 7) in radians."""

    name = "arm7"
    n_joints = 7
    a = np.array([0.0, 0.3, 0.4, 0.5, 0.39, 0.0, 0.2])
    alpha = np.array([np.pi / 2, -np.pi / 2, -np.pi / 2, np.pi / 2, np.pi / 2, -np.pi / 2, 0.0])
    d = np.zeros(7)
    #: joint limits in degrees (symmetric)
    limits_deg = np.array([170.0, 120.0, 170.0, 120.0, 170.0, 120.0, 170.0])

    def frames(self, Q: np.ndarray) -> np.ndarray:
        """Homogeneous transforms of frames 0..7 in the base frame: (N, 8, 4, 4)."""
        n = Q.shape[0]
        T = np.empty((n, 8, 4, 4))
        T[:, 0] = np.eye(4)
        ca, sa = np.cos(self.alpha), np.sin(self.alpha)
        for i in range(7):  # loop over joints, batched over postures
            ct, st = np.cos(Q[:, i]), np.sin(Q[:, i])
            A = np.zeros((n, 4, 4))
            A[:, 0, 0], A[:, 0, 1], A[:, 0, 2], A[:, 0, 3] = ct, -st * ca[i], st * sa[i], self.a[i] * ct
            A[:, 1, 0], A[:, 1, 1], A[:, 1, 2], A[:, 1, 3] = st, ct * ca[i], -ct * sa[i], self.a[i] * st
            A[:, 2, 1], A[:, 2, 2], A[:, 2, 3] = sa[i], ca[i], self.d[i]
            A[:, 3, 3] = 1.0
            T[:, i + 1] = T[:, i] @ A
        return T

    def forward(self, Q: np.ndarray) -> np.ndarray:
        """End-effector position (N, 3)."""
        return self.frames(Q)[:, 7, :3, 3]

    def jacobian(self, Q: np.ndarray) -> np.ndarray:
        """Geometric Jacobian (N, 6, 7): rows (v_x, v_y, v_z, ω_x, ω_y, ω_z).

        Column i: [z_{i−1} × (o_7 − o_{i−1}); z_{i−1}] for revolute joint i.
        """
        T = self.frames(Q)
        z = T[:, :7, :3, 2]
        o = T[:, :7, :3, 3]
        o_end = T[:, 7, :3, 3][:, None, :]
        J = np.empty((Q.shape[0], 6, 7))
        J[:, :3, :] = np.cross(z, o_end - o).transpose(0, 2, 1)
        J[:, 3:, :] = z.transpose(0, 2, 1)
        return J


#: The built-in arms by name.
ARMS = dict(zip(get_args(ArmName), (TwoLinkArm, SevenDofArm), strict=True))


class ArmFeatures:
    """Known constraint features Φ(x) = selected rows of an arm's Jacobian (§3.3).

    Args:
        arm: ``"arm2"`` or ``"arm7"``.
        rows: Jacobian rows to keep (default all).
    """

    def __init__(self, arm: str = "arm2", rows: list[int] | None = None) -> None:
        if arm not in ARMS:
            raise ValueError(f"unknown arm {arm!r} (known: {', '.join(ARMS)})")
        self.arm = arm
        self.rows = rows
        self._model = ARMS[arm]()

    def __call__(self, X: np.ndarray) -> np.ndarray:
        """Φ(X) (N, len(rows), n_joints) for joint angles X (N, n_joints); a state of another
        width, or rows beyond the Jacobian's, is an InputError naming both."""
        X = np.asarray(X, dtype=float)
        n = self._model.n_joints
        if X.ndim != 2 or X.shape[1] != n:
            got = f"{X.shape[1]} columns" if X.ndim == 2 else f"shape {X.shape}"
            raise InputError(f"features {self.arm} need the {n} joint angles of the arm per sample "
                             f"(state of {n} columns), got {got}")
        J = self._model.jacobian(X)
        if self.rows is None:
            return J
        bad = [r for r in self.rows if not -J.shape[1] <= int(r) < J.shape[1]]
        if bad:
            raise InputError(f"features {self.arm}: rows {bad} are beyond its Jacobian's {J.shape[1]} rows")
        return J[:, list(self.rows), :]

    def spec(self) -> dict:
        return {"kind": "arm", "arm": self.arm, "rows": self.rows}
