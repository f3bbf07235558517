"""MJCF (MuJoCo XML) → :class:`~ccl_cli.learn.robots.chain.Chain`, read and compiled by MuJoCo
itself (``pip install 'ccl_cli[robots]'``): defaults classes, ``<compiler angle>``, Euler
sequences, includes and frames are resolved by the library that defines the format.

From the compiled model, the bodies from ``base`` (default: the world) to the body of ``frame``
(a site or a body) give the chain. A body contributes its fixed pose in its parent
(``body_pos``, ``body_quat``) and then its hinge / slide joints in order; joint j with anchor
c_j and axis a_j (body frame) moves the body by T(c_j) M_j(q_j − ref_j) T(−c_j), where ref_j
(``qpos0``) is the joint value at which the body has its modelled pose. A site adds its pose
in its body.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

import numpy as np

from ccl_cli.errors import ConfigError, InputError
from ccl_cli.learn.robots.chain import Chain, Joint
from ccl_cli.learn.robots.transforms import axis_angle_matrices, homogeneous, quaternion_matrix

#: the message when MuJoCo is not installed
NEEDS_EXTRA = "robot: MJCF needs MuJoCo: pip install 'ccl_cli[robots]'"


def _mujoco() -> Any:
    try:
        import mujoco
    except ImportError:
        raise ConfigError(NEEDS_EXTRA) from None
    return mujoco


def _pose(pos: np.ndarray, quat: np.ndarray) -> np.ndarray:
    return homogeneous(quaternion_matrix(quat), pos)


def mjcf_chain(model: Any, frame: str, base: str | None = None, source: str = "MJCF") -> Chain:
    """The chain of a compiled ``mujoco.MjModel`` from body ``base`` (default: the world) to the
    site or body ``frame``."""
    mujoco = _mujoco()
    obj = mujoco.mjtObj

    def name(kind: Any, i: int) -> str:
        return mujoco.mj_id2name(model, kind, i) or ""

    site = mujoco.mj_name2id(model, obj.mjOBJ_SITE, frame)
    body = int(model.site_bodyid[site]) if site >= 0 else mujoco.mj_name2id(model, obj.mjOBJ_BODY, frame)
    if body < 0:
        bodies = [name(obj.mjOBJ_BODY, i) for i in range(1, model.nbody)]
        sites = [name(obj.mjOBJ_SITE, i) for i in range(model.nsite)]
        raise InputError(f"{source}: frame {frame!r} is neither a site nor a body "
                         f"(bodies: {', '.join(bodies) or 'none'}; sites: {', '.join(sites) or 'none'})")
    top = 0 if base is None else mujoco.mj_name2id(model, obj.mjOBJ_BODY, base)
    if top < 0:
        raise InputError(f"{source}: base {base!r} is not a body")
    path = []
    while body != top:
        if body == 0:
            raise InputError(f"{source}: frame {frame!r} is not below base {base!r}")
        path.append(body)
        body = int(model.body_parentid[body])
    joints: list[Joint] = []
    for b in reversed(path):
        bname = name(obj.mjOBJ_BODY, b) or f"body{b}"
        pending = _pose(model.body_pos[b], model.body_quat[b])
        for j in range(model.body_jntadr[b], model.body_jntadr[b] + model.body_jntnum[b]):
            jname = name(obj.mjOBJ_JOINT, j) or f"{bname}_joint{j}"
            kind, axis = int(model.jnt_type[j]), np.asarray(model.jnt_axis[j], dtype=float)
            ref = float(model.qpos0[model.jnt_qposadr[j]])
            if kind == mujoco.mjtJoint.mjJNT_HINGE:
                kind_name = "revolute" if model.jnt_limited[j] else "continuous"
                offset = homogeneous(axis_angle_matrices(axis / np.linalg.norm(axis), np.array([-ref]))[0])
            elif kind == mujoco.mjtJoint.mjJNT_SLIDE:
                kind_name, offset = "prismatic", homogeneous(p=-ref * axis / np.linalg.norm(axis))
            else:
                raise InputError(f"{source}: joint {jname!r} of body {bname!r} is a "
                                 f"{'ball' if kind == mujoco.mjtJoint.mjJNT_BALL else 'free'} joint; "
                                 "a chain supports hinge and slide joints (choose a base below it)")
            lower, upper = model.jnt_range[j] if model.jnt_limited[j] else (-np.inf, np.inf)
            anchor = np.asarray(model.jnt_pos[j], dtype=float)
            origin = pending @ homogeneous(p=anchor) @ offset
            joints.append(Joint(jname, kind_name, origin, axis, lower, upper))
            pending = homogeneous(p=-anchor)
        joints.append(Joint(f"{bname}_pose", "fixed", pending))
    if site >= 0:
        joints.append(Joint(f"{frame}_site", "fixed", _pose(model.site_pos[site], model.site_quat[site])))
    root = "world" if top == 0 else str(base)
    return Chain(tuple(joints), base=root, frame=frame, source=source)


def read_mjcf(path: str | Path, frame: str, base: str | None = None) -> Chain:
    """The chain from body ``base`` (default: the world) to the site or body ``frame`` of an MJCF
    file, compiled by MuJoCo (meshes it references must be present)."""
    mujoco = _mujoco()
    try:
        model = mujoco.MjModel.from_xml_path(str(path))
    except ValueError as e:
        detail = " ".join(str(e).removeprefix("Error: ").split())
        raise InputError(f"{path}: MuJoCo cannot load it ({detail})") from None
    return mjcf_chain(model, frame, base, str(path))
