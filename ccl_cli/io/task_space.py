"""Task space from joint logs (``state: {..., forward_kinematics: {robot, frame, base, orientation}}``).

The joint columns q (N, n) of a log become the end-effector pose of the chain's frame,
x = FK(q): positions (x, y, z) in m and, on request, unit quaternions (qw, qx, qy, qz) kept
on one hemisphere along the log (q and −q are one rotation; a sign flip would be a jump). A
recorded joint-velocity action q̇ is mapped through the Jacobian: v = J_p(q) q̇ (N, 3)
(ALGORITHMS.md §3.3: the constraint at the end effector, A(q) = nᵀJ_p(q)); otherwise the
action is derived from x as for any state.

The log's joint names (a JointState's ``joints``, CSV headers, HDF5 name attributes) are
matched to the chain's with :func:`ccl_cli.learn.robots.match_joints` (any order, one common
prefix allowed); a JointState topic without ``joints`` is read by the chain's joint names; a
log without names (.mat matrices) is taken in the chain's joint order and must have its
number of columns.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Any

import numpy as np

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.io.options import ForwardKinematicsOptions, StreamOptions

if TYPE_CHECKING:  # the robot models load on first use: reading a log without kinematics skips them
    from ccl_cli.learn.robots import Chain

POSITION_NAMES = ["x", "y", "z"]
QUATERNION_NAMES = ["qw", "qx", "qy", "qz"]


@dataclass
class JointMap:
    """A chain and the log columns of its joints (``Q_chain = Q_log[:, index]``)."""

    chain: Chain
    index: np.ndarray
    options: ForwardKinematicsOptions

    @property
    def names(self) -> list[str]:
        """Names of the task-space state: x, y, z (and qw, qx, qy, qz)."""
        return POSITION_NAMES + (QUATERNION_NAMES if self.options.orientation else [])

    @property
    def units(self) -> list[str]:
        return ["m"] * 3 + (["1"] * 4 if self.options.orientation else [])

    def pose(self, Q: np.ndarray) -> np.ndarray:
        """Joint log (N, d) → task-space state (N, 3) or (N, 7)."""
        pose = self.chain.forward(Q[:, self.index])
        if not self.options.orientation:
            return pose.position
        from ccl_cli.learn.robots import quaternions

        return np.hstack([pose.position, continuous(quaternions(pose.rotation))])

    def velocity(self, Q: np.ndarray, dQ: np.ndarray) -> np.ndarray:
        """v = J_p(q) q̇: joint log (N, d) and joint velocities (N, d) → (N, 3) m/s."""
        J = self.chain.jacobian(Q[:, self.index], rows=[0, 1, 2])
        return np.einsum("nij,nj->ni", J, dQ[:, self.index])

    def describe(self) -> dict[str, Any]:
        """What was computed, for the dataset's metadata."""
        return {"robot": self.chain.describe(), "frame": self.chain.frame, "base": self.chain.base,
                "joints": self.chain.joint_names, "state": self.names, "units": self.units}


def continuous(quat: np.ndarray) -> np.ndarray:
    """Quaternions (N, 4) with signs chosen so that consecutive ones have a positive dot product."""
    if len(quat) < 2:
        return quat
    flips = np.r_[1.0, np.where(np.einsum("ij,ij->i", quat[1:], quat[:-1]) < 0, -1.0, 1.0)]
    return quat * np.cumprod(flips)[:, None]


def with_joints(selection: StreamOptions, options: ForwardKinematicsOptions | None,
                joints: list[str] | None = None) -> StreamOptions:
    """A JointState ``selection`` (a topic) without ``joints`` reads ``joints`` (the state's, for
    the action: the same columns in the same order), else the robot's joints by name in the
    chain's order; any other selection as it is."""
    if options is None or selection.topic is None or selection.joints is not None:
        return selection
    return selection.model_copy(update={"joints": joints or _chain(options, selection.topic).joint_names})


def log_joint_names(selection: StreamOptions, names: list[str]) -> list[str]:
    """The joint names of a log's columns: a JointState's ``joints``, else the column names."""
    return list(selection.joints) if selection.joints is not None else names


def _chain(options: ForwardKinematicsOptions, where: str) -> Chain:
    from ccl_cli.learn.robots import load_robot

    try:
        return load_robot(options.robot, options.frame, options.base)
    except (ConfigError, InputError) as exc:
        raise InputError(f"{where}: state.forward_kinematics: {exc}") from None


def joint_map(options: ForwardKinematicsOptions, log_names: list[str] | None, n_columns: int,
              where: str) -> JointMap:
    """The chain of ``options`` and the columns of the log holding its joints: by name when the
    log names its columns (``log_names``), else by position (``n_columns`` must equal the
    chain's joint count). Errors name the file, the robot and the joints at fault."""
    chain = _chain(options, where)
    if log_names is None:
        if n_columns != chain.n_joints:
            raise InputError(f"{where}: state.forward_kinematics: the log has {n_columns} joint columns, "
                             f"{chain.describe()} has {chain.n_joints} ({', '.join(chain.joint_names)})")
        return JointMap(chain, np.arange(n_columns), options)
    try:
        from ccl_cli.learn.robots import match_joints

        index = match_joints(log_names, chain.joint_names, what=chain.describe())
    except InputError as exc:
        raise InputError(f"{where}: state.forward_kinematics: {exc}") from None
    return JointMap(chain, index, options)


def to_task_space(Q: np.ndarray, dQ: np.ndarray | None, options: ForwardKinematicsOptions,
                  log_names: list[str] | None, where: str
                  ) -> tuple[np.ndarray, np.ndarray | None, JointMap]:
    """Joint log Q (N, d) and recorded joint velocities dQ (N, d) or None → task-space state
    (N, 3 | 7), the action v = J_p(q) q̇ (N, 3) or None, and the :class:`JointMap` used."""
    joints = joint_map(options, log_names, Q.shape[1], where)
    if dQ is not None and options.orientation:
        raise InputError(f"{where}: state.forward_kinematics: orientation with a recorded action maps "
                         "joint velocities to 3 linear velocities for a 7-column state; derive the "
                         "action (action: {derive: state}) or set orientation: false")
    if dQ is not None and dQ.shape[1] != Q.shape[1]:
        raise InputError(f"{where}: state.forward_kinematics: the action has {dQ.shape[1]} columns, the "
                         f"joint state {Q.shape[1]}; give the joint velocities in the state's columns")
    U = joints.velocity(Q, dQ) if dQ is not None else None
    return joints.pose(Q), U, joints
