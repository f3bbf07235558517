"""Robot models from the files robotics users have — URDF, MJCF and Denavit–Hartenberg tables — as
serial kinematic chains with batched forward kinematics and geometric Jacobians.

* :class:`Chain`, :class:`Joint`, :class:`Pose` — the chain base → frame and its kinematics;
* :func:`read_urdf`, :func:`parse_urdf` — a URDF file or text → Chain (standard-library XML,
  document type declarations refused);
* :func:`read_mjcf`, :func:`mjcf_chain` — an MJCF file (or a compiled ``mujoco.MjModel``) → Chain,
  read by MuJoCo (the ``robots`` extra);
* :func:`dh_chain`, :func:`dh_urdf`, :func:`chain_urdf` — DH tables (standard or modified) → Chain
  or URDF text;
* :func:`load_robot` — a URDF / MJCF path or a ``{"dh": [...]}`` mapping (a run spec's
  ``robot:``) → Chain;
* :func:`match_joints` — a log's joint names → the chain's columns;
* :class:`RobotFeatures`, :func:`robot_features` — Φ(q) = rows of J(q), the known features of
  the lambda constraint (``features: {robot: ..., frame: ..., rows: [...]}``);
* :data:`LWR4`, :data:`PANDA` — published DH tables (:class:`DHRobot`: ``.chain()``, ``.urdf()``).
"""

from __future__ import annotations

from ccl_cli.learn.robots.chain import CHUNK_POSTURES, JOINT_TYPES, Chain, Joint, Pose
from ccl_cli.learn.robots.dh import chain_urdf, dh_chain, dh_urdf
from ccl_cli.learn.robots.features import RobotFeatures, robot_features
from ccl_cli.learn.robots.load import load_robot
from ccl_cli.learn.robots.mjcf import mjcf_chain, read_mjcf
from ccl_cli.learn.robots.names import match_joints
from ccl_cli.learn.robots.tables import LWR4, PANDA, DHRobot
from ccl_cli.learn.robots.transforms import quaternions
from ccl_cli.learn.robots.urdf import parse_urdf, read_urdf

__all__ = ["CHUNK_POSTURES", "JOINT_TYPES", "LWR4", "PANDA", "Chain", "DHRobot", "Joint", "Pose",
           "RobotFeatures", "chain_urdf", "dh_chain", "dh_urdf", "load_robot", "match_joints", "mjcf_chain",
           "parse_urdf", "quaternions", "read_mjcf", "read_urdf", "robot_features"]
