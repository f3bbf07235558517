"""A serial kinematic chain and its batched forward kinematics and geometric Jacobian.

A :class:`Chain` is the list of joints from a base link to a chosen frame, each with its fixed
origin (the transform from the parent link to the joint frame, URDF ``<origin>``), its axis in
the joint frame and its type. For postures Q (N, n) of the n moving joints, with T_j the origin
of joint j and M_j(q_j) its motion (a rotation about, or a translation along, its axis),

    T_frame(q) = Π_j T_j M_j(q_j)                                    (forward kinematics)

and column j of the geometric Jacobian in the base frame (rows v_x, v_y, v_z, ω_x, ω_y, ω_z) is

    revolute / continuous:  [z_j × (p − o_j); z_j],    prismatic:  [z_j; 0],

with z_j the joint axis and o_j the joint origin in the base frame, p the frame's position
(ALGORITHMS.md §7 uses it for the 7-DoF arm). Fixed joints are folded into the next origin.
Postures are processed in chunks of :data:`CHUNK_POSTURES`, so the working memory does not grow
with N; each joint costs one product of a (3 c, 3) block with a constant (3, 4) matrix.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass, field
from functools import cached_property
from typing import NamedTuple

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.linalg import row_chunks
from ccl_cli.learn.robots.transforms import homogeneous, z_to_axis

#: Postures per block of the batched kinematics: its arrays stay in cache, and its (3 c, 3) products
#: stay below the size at which OpenBLAS starts threads (which stall on a shared machine).
CHUNK_POSTURES = 4096

#: Joint types of a chain (URDF names); ``continuous`` is a revolute joint without limits.
JOINT_TYPES = ("revolute", "continuous", "prismatic", "fixed")


@dataclass(frozen=True, eq=False)
class Joint:
    """One joint: ``origin`` (4, 4) maps the joint frame to its parent link's frame; ``axis`` (3,)
    is a unit vector in the joint frame; limits in rad or m (±inf when unlimited)."""

    name: str
    type: str
    origin: np.ndarray
    axis: np.ndarray = field(default_factory=lambda: np.array([0.0, 0.0, 1.0]))
    lower: float = -np.inf
    upper: float = np.inf
    parent: str = ""
    child: str = ""

    def __post_init__(self) -> None:
        if self.type not in JOINT_TYPES:
            raise InputError(f"joint {self.name!r}: type {self.type!r} is not one of "
                             f"{', '.join(JOINT_TYPES)}")
        axis = np.asarray(self.axis, dtype=float)
        norm = float(np.linalg.norm(axis))
        if self.type != "fixed" and not norm > 1e-12:
            raise InputError(f"joint {self.name!r}: axis {axis.tolist()} has zero length")
        object.__setattr__(self, "axis", axis / norm if norm > 1e-12 else axis)
        object.__setattr__(self, "origin", np.asarray(self.origin, dtype=float).reshape(4, 4))
        object.__setattr__(self, "lower", float(self.lower))
        object.__setattr__(self, "upper", float(self.upper))


class Pose(NamedTuple):
    """Poses of the chain's frame in the base frame: ``position`` (N, 3), ``rotation`` (N, 3, 3)."""

    position: np.ndarray
    rotation: np.ndarray


@dataclass(frozen=True, eq=False)
class Chain:
    """A serial chain from ``base`` to ``frame``: ``joints`` in order, fixed ones included.

    ``source`` names where it came from (a file, ``DH table``) for error messages.
    """

    joints: tuple[Joint, ...]
    base: str = "base"
    frame: str = "frame"
    source: str = "robot"

    @property
    def moving(self) -> tuple[Joint, ...]:
        """The joints a posture sets (all but the fixed ones), in chain order."""
        return tuple(j for j in self.joints if j.type != "fixed")

    @property
    def joint_names(self) -> list[str]:
        return [j.name for j in self.moving]

    @property
    def n_joints(self) -> int:
        return len(self.moving)

    @property
    def lower(self) -> np.ndarray:
        """Lower joint limits (n,) in rad or m; −inf when unlimited."""
        return np.array([j.lower for j in self.moving])

    @property
    def upper(self) -> np.ndarray:
        """Upper joint limits (n,); +inf when unlimited."""
        return np.array([j.upper for j in self.moving])

    def describe(self) -> str:
        """``source base→frame (n joints)``, for messages."""
        return f"{self.source} {self.base}→{self.frame} ({self.n_joints} joints)"

    @cached_property
    def _steps(self) -> tuple[list[tuple[np.ndarray, str]], np.ndarray]:
        """Per moving joint: the fixed transform before it (4, 4), in a joint frame turned so that
        its axis is z, and its type; and the fixed transform from the last joint to the frame.

        A joint about (along) the unit axis a moves by S R_z(q) Sᵀ (S T_z(q) Sᵀ) with S e_z = a, so
        S joins the joint's origin and Sᵀ the transform after it."""
        steps, pending = [], np.eye(4)
        for j in self.joints:
            pending = pending @ j.origin
            if j.type != "fixed":
                S = homogeneous(z_to_axis(j.axis))
                steps.append((pending @ S, j.type))
                pending = S.T
        return steps, pending

    def _postures(self, Q: np.ndarray) -> np.ndarray:
        Q = np.asarray(Q, dtype=float)
        if Q.ndim == 1 and self.n_joints > 0 and Q.size == self.n_joints:
            Q = Q[None, :]
        if Q.ndim != 2 or Q.shape[1] != self.n_joints:
            raise InputError(f"postures have shape {Q.shape}; {self.describe()} needs (N, {self.n_joints}) "
                             f"with columns {', '.join(self.joint_names)}")
        return Q

    def _chunk(self, Q: np.ndarray, jacobian: bool
               ) -> tuple[np.ndarray, np.ndarray, np.ndarray | None]:
        """Frame pose and (optionally) Jacobian of one block of postures Q (c, n).

        Per joint, one product of the rotations so far R (3 c, 3) with the joint's fixed origin
        [A, t] (3, 4) gives its rotation R A, whose third column is the joint axis z_j, and its
        origin o_j = p + R t; a revolute joint then mixes the first two columns by R_z(q).
        """
        c = Q.shape[0]
        steps, tail = self._steps
        R = np.broadcast_to(np.eye(3), (c, 3, 3))
        p = np.zeros((c, 3))
        axes = np.empty((c if jacobian else 0, 3, len(steps)))  # joint axes z_j and origins o_j
        origins = np.empty_like(axes)
        for k, (T, kind) in enumerate(steps):  # a loop over joints; each step batched over postures
            X = (np.reshape(R, (-1, 3)) @ T[:3, :]).reshape(c, 3, 4)  # [R A, R t]
            p = p + X[:, :, 3]
            z = X[:, :, 2]
            if jacobian:
                axes[:, :, k], origins[:, :, k] = z, p
            if kind == "prismatic":
                R = X[:, :, :3]
                p = p + z * Q[:, k, None]
            else:
                cq, sq = np.cos(Q[:, k])[:, None], np.sin(Q[:, k])[:, None]
                R = np.empty((c, 3, 3))
                R[:, :, 0] = cq * X[:, :, 0] + sq * X[:, :, 1]
                R[:, :, 1] = cq * X[:, :, 1] - sq * X[:, :, 0]
                R[:, :, 2] = z
        X = (np.reshape(R, (-1, 3)) @ tail[:3, :]).reshape(c, 3, 4)
        R, p = X[:, :, :3], p + X[:, :, 3]
        if not jacobian:
            return p, R, None
        d = p[:, :, None] - origins  # o_j → frame (c, 3, n)
        J = np.empty((c, 6, len(steps)))
        J[:, 0] = axes[:, 1] * d[:, 2] - axes[:, 2] * d[:, 1]  # z_j × (p − o_j)
        J[:, 1] = axes[:, 2] * d[:, 0] - axes[:, 0] * d[:, 2]
        J[:, 2] = axes[:, 0] * d[:, 1] - axes[:, 1] * d[:, 0]
        J[:, 3:] = axes
        prismatic = [k for k, (_, kind) in enumerate(steps) if kind == "prismatic"]
        if prismatic:
            J[:, :3, prismatic], J[:, 3:, prismatic] = axes[:, :, prismatic], 0.0
        return p, R, J

    def forward(self, Q: np.ndarray, chunk: int | None = None) -> Pose:
        """Pose of ``frame`` in the base frame for postures Q (N, n): positions (N, 3), rotations
        (N, 3, 3)."""
        Q = self._postures(Q)
        P, Rs = np.empty((len(Q), 3)), np.empty((len(Q), 3, 3))
        for block in row_chunks(len(Q), chunk or CHUNK_POSTURES):
            P[block], Rs[block], _ = self._chunk(Q[block], jacobian=False)
        return Pose(P, Rs)

    def jacobian(self, Q: np.ndarray, rows: Sequence[int] | None = None, chunk: int | None = None
                 ) -> np.ndarray:
        """Geometric Jacobian of ``frame`` in the base frame, Q (N, n) → (N, 6, n), rows
        (v_x, v_y, v_z, ω_x, ω_y, ω_z); only ``rows`` of them (N, len(rows), n) when given."""
        Q = self._postures(Q)
        keep = list(range(6)) if rows is None else [int(r) for r in rows]
        if any(not 0 <= r < 6 for r in keep):
            raise InputError(f"Jacobian rows {keep} must lie in 0..5 (v_x, v_y, v_z, ω_x, ω_y, ω_z)")
        out = np.empty((len(Q), len(keep), self.n_joints))
        for block in row_chunks(len(Q), chunk or CHUNK_POSTURES):
            out[block] = self._chunk(Q[block], jacobian=True)[2][:, keep, :]
        return out

    def forward_jacobian(self, Q: np.ndarray, chunk: int | None = None
                         ) -> tuple[Pose, np.ndarray]:
        """:meth:`forward` and :meth:`jacobian` in one pass: (Pose, (N, 6, n))."""
        Q = self._postures(Q)
        P, Rs, J = np.empty((len(Q), 3)), np.empty((len(Q), 3, 3)), np.empty((len(Q), 6, self.n_joints))
        for block in row_chunks(len(Q), chunk or CHUNK_POSTURES):
            P[block], Rs[block], J[block] = self._chunk(Q[block], jacobian=True)
        return Pose(P, Rs), J
