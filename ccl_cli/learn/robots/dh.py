"""Denavit–Hartenberg tables → :class:`~ccl_cli.learn.robots.chain.Chain`, and → URDF text.

A table has one row ``[a, d, alpha, theta0]`` per joint (metres, radians), as users of the
original MATLAB library write them. Joint i adds q_i to theta (revolute) or to d (prismatic):

* standard DH:  ᶦ⁻¹T_i = R_z(θ_i) T_z(d_i) T_x(a_i) R_x(α_i)
* modified DH (Craig), row i = [a_{i−1}, d_i, α_{i−1}, θ_i]:
  ᶦ⁻¹T_i = R_x(α_{i−1}) T_x(a_{i−1}) R_z(θ_i) T_z(d_i)

with θ_i = theta0_i (+ q_i) and d_i = d (+ q_i). The chain's frame is the last DH frame followed
by an optional fixed ``tip`` transform (4, 4), e.g. a flange or tool offset.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.robots.chain import Chain, Joint
from ccl_cli.learn.robots.transforms import homogeneous, matrix_rpy, rot_x, rot_z, translation


def _table(table: Sequence[Sequence[float]] | np.ndarray) -> np.ndarray:
    try:
        T = np.asarray(table, dtype=float)
    except (TypeError, ValueError):
        raise InputError("DH table: rows must be [a, d, alpha, theta0] numbers") from None
    if T.ndim != 2 or T.shape[1] != 4 or T.shape[0] == 0:
        raise InputError(f"DH table: shape {T.shape}; expected one row [a, d, alpha, theta0] per joint")
    if not np.isfinite(T).all():
        raise InputError("DH table: every entry must be a finite number")
    return T


def _types(types: str | Sequence[str] | None, n: int) -> list[str]:
    """``"RRP..."`` or ``["revolute", "prismatic", ...]`` → URDF type names (default all revolute)."""
    if types is None:
        return ["revolute"] * n
    letters = {"r": "revolute", "p": "prismatic", "revolute": "revolute", "prismatic": "prismatic"}
    items = list(types) if isinstance(types, str) else list(types)
    out = [letters.get(str(t).lower()) for t in items]
    if len(out) != n or None in out:
        raise InputError(f"DH joint types {types!r}: need {n} of R (revolute) / P (prismatic)")
    return [str(t) for t in out]


def dh_chain(table: Sequence[Sequence[float]] | np.ndarray, *, modified: bool = False,
             types: str | Sequence[str] | None = None, names: Sequence[str] | None = None,
             tip: np.ndarray | None = None, limits: Sequence[Sequence[float]] | np.ndarray | None = None,
             base: str = "base", frame: str = "tip", source: str = "DH table") -> Chain:
    """The chain of a DH table (rows ``[a, d, alpha, theta0]``; ``modified`` for Craig's convention).

    Args:
        types: per joint ``R``/``P`` (default all revolute).
        names: joint names (default ``joint1`` … ``jointN``).
        tip: fixed transform (4, 4) from the last DH frame to ``frame``.
        limits: (n, 2) lower/upper joint limits (default unlimited).
    """
    T = _table(table)
    n = len(T)
    kinds = _types(types, n)
    names = [f"joint{i + 1}" for i in range(n)] if names is None else [str(s) for s in names]
    if len(names) != n or len(set(names)) != n:
        raise InputError(f"DH table: {n} joints need {n} distinct names, got {names}")
    lim = np.full((n, 2), [-np.inf, np.inf]) if limits is None else np.asarray(limits, dtype=float)
    if lim.shape != (n, 2):
        raise InputError(f"DH table: limits have shape {lim.shape}, expected ({n}, 2)")
    joints, after = [], np.eye(4)  # ``after``: the fixed part of the previous row, not yet placed
    for i, (a, d, alpha, theta0) in enumerate(T):
        if modified:  # R_x(α) T_x(a) R_z(θ0) · [motion] · T_z(d); T_z(d) commutes with R_z
            origin = after @ homogeneous(rot_x(alpha)) @ translation(a) @ homogeneous(rot_z(theta0))
            after = translation(z=d)
        else:  # R_z(θ0) · [motion] · T_z(d) T_x(a) R_x(α)
            origin = after @ homogeneous(rot_z(theta0))
            after = translation(z=d) @ translation(a) @ homogeneous(rot_x(alpha))
        joints.append(Joint(names[i], kinds[i], origin, np.array([0.0, 0.0, 1.0]), lim[i, 0], lim[i, 1],
                            f"link{i}", f"link{i + 1}"))
    tail = after if tip is None else after @ np.asarray(tip, dtype=float).reshape(4, 4)
    joints.append(Joint(f"{frame}_joint", "fixed", tail, parent=f"link{n}", child=frame))
    return Chain(tuple(joints), base=base, frame=frame, source=source)


def chain_urdf(chain: Chain, robot: str = "robot") -> str:
    """URDF text of a chain: one link per frame, one joint per chain joint (origin as xyz + rpy).

    Link names are the chain's (``base``, the joints' children, ``frame``); no geometry or
    inertia is written, so the file describes kinematics only. A revolute joint without
    finite limits is written as ``continuous``.
    """
    from xml.sax.saxutils import quoteattr  # imports urllib, http and ssl: only when a chain is written

    lines = ['<?xml version="1.0"?>', f"<robot name={quoteattr(robot)}>",
             f"  <link name={quoteattr(chain.base)}/>"]
    parent = chain.base
    for k, j in enumerate(chain.joints):
        child = chain.frame if k == len(chain.joints) - 1 else (j.child or f"{j.name}_link")
        xyz = " ".join(repr(float(v)) for v in j.origin[:3, 3])
        rpy = " ".join(repr(float(v)) for v in matrix_rpy(j.origin[:3, :3]))
        lines.append(f"  <link name={quoteattr(child)}/>")
        kind = j.type
        if kind == "revolute" and not np.isfinite([j.lower, j.upper]).all():
            kind = "continuous"  # URDF's name for a revolute joint without limits
        elif kind == "prismatic" and not np.isfinite([j.lower, j.upper]).all():
            raise InputError(f"{chain.source}: prismatic joint {j.name!r} needs finite limits in a URDF")
        lines.append(f"  <joint name={quoteattr(j.name)} type={quoteattr(kind)}>")
        lines.append(f"    <parent link={quoteattr(parent)}/>\n    <child link={quoteattr(child)}/>")
        lines.append(f'    <origin xyz="{xyz}" rpy="{rpy}"/>')
        if j.type != "fixed":
            lines.append(f'    <axis xyz="{" ".join(repr(float(v)) for v in j.axis)}"/>')
        if kind in ("revolute", "prismatic"):
            lines.append(f'    <limit lower="{j.lower!r}" upper="{j.upper!r}" effort="0" velocity="0"/>')
        lines.append("  </joint>")
        parent = child
    lines.append("</robot>\n")
    return "\n".join(lines)


def dh_urdf(table: Sequence[Sequence[float]] | np.ndarray, *, modified: bool = False, robot: str = "robot",
            **kwargs: object) -> str:
    """URDF text of a DH table (the arguments of :func:`dh_chain`)."""
    return chain_urdf(dh_chain(table, modified=modified, **kwargs), robot=robot)  # type: ignore[arg-type]
