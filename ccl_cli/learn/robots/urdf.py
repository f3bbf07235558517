"""URDF → :class:`~ccl_cli.learn.robots.chain.Chain`: the joints from a base link to a frame.

Only the kinematic part of a URDF is read: ``<link name>`` and ``<joint name type>`` with
``<parent link>``, ``<child link>``, ``<origin xyz rpy>`` (zeros by default), ``<axis xyz>``
((1, 0, 0) by default) and ``<limit lower upper>``. Geometry, inertia and meshes are not opened.
A chain is the unique path of joints from ``base`` (by default the root link) to ``frame``.
"""

from __future__ import annotations

import xml.etree.ElementTree as ET
from pathlib import Path

import numpy as np

from ccl_cli.errors import InputError
from ccl_cli.learn.robots.chain import JOINT_TYPES, Chain, Joint
from ccl_cli.learn.robots.transforms import origin_matrix
from ccl_cli.learn.robots.xmlsafe import floats, parse_xml, read_xml

#: Every joint type the URDF format defines; the chain to the frame may use :data:`JOINT_TYPES`.
URDF_JOINT_TYPES = (*JOINT_TYPES, "floating", "planar")


def _joint(el: ET.Element, source: str) -> tuple[Joint | None, str, str, str]:
    """(joint, its type, parent link, child link) of one ``<joint>``; joint None for floating/planar."""
    name = el.get("name")
    what = f"{source}: joint {name!r}"
    if not name:
        raise InputError(f"{source}: a <joint> has no name")
    kind = el.get("type")
    if kind not in URDF_JOINT_TYPES:
        raise InputError(f"{what} has type {kind!r}; URDF joint types are {', '.join(URDF_JOINT_TYPES)}")
    links = []
    for tag in ("parent", "child"):
        sub = el.find(tag)
        if sub is None or not sub.get("link"):
            raise InputError(f"{what} has no <{tag} link=...>")
        links.append(sub.get("link"))
    if kind in ("floating", "planar"):
        return None, kind, links[0], links[1]
    if el.find("mimic") is not None:
        raise InputError(f"{what} mimics another joint; a chain's joints must be set independently")
    o = el.find("origin")
    xyz = floats(None if o is None else o.get("xyz"), 3, (0.0, 0.0, 0.0), f"{what} origin xyz")
    rpy = floats(None if o is None else o.get("rpy"), 3, (0.0, 0.0, 0.0), f"{what} origin rpy")
    a = el.find("axis")
    axis = floats(None if a is None else a.get("xyz"), 3, (1.0, 0.0, 0.0), f"{what} axis xyz")
    lower, upper = -np.inf, np.inf
    lim = el.find("limit")
    if lim is not None and kind in ("revolute", "prismatic"):
        lower = floats(lim.get("lower"), 1, (0.0,), f"{what} limit lower")[0]
        upper = floats(lim.get("upper"), 1, (0.0,), f"{what} limit upper")[0]
    try:
        joint = Joint(name, kind, origin_matrix(np.array(xyz), np.array(rpy)), np.array(axis),
                      lower, upper, links[0], links[1])
    except InputError as e:
        raise InputError(f"{source}: {e.message}") from None
    return joint, kind, links[0], links[1]


def urdf_chain(root: ET.Element, frame: str | None, base: str | None = None, source: str = "URDF") -> Chain:
    """The chain of a parsed URDF (its ``<robot>`` element) from ``base`` to the link ``frame``
    (default: the one link without children, when there is exactly one)."""
    if any(":" in el.tag and el.tag.split(":")[0] == "xacro" for el in root.iter()):
        raise InputError(f"{source} is a xacro file; expand it first (xacro {source} > robot.urdf)")
    if root.tag != "robot":
        raise InputError(f"{source} is not a URDF: its root element is <{root.tag}>, not <robot>")
    links = [el.get("name") for el in root.findall("link")]
    if len(set(links)) != len(links):
        dup = sorted({n for n in links if links.count(n) > 1})
        raise InputError(f"{source}: links named more than once: {', '.join(map(str, dup))}")
    parent_of: dict[str, tuple[Joint | None, str, str]] = {}  # child link → (joint, type, parent link)
    names: set[str] = set()
    for el in root.findall("joint"):
        joint, kind, parent, child = _joint(el, source)
        name = el.get("name", "")
        if name in names:
            raise InputError(f"{source}: joint {name!r} is defined twice")
        names.add(name)
        for link in (parent, child):
            if link not in links:
                raise InputError(f"{source}: joint {name!r} refers to link {link!r}, which is not defined")
        if child in parent_of:
            raise InputError(f"{source}: link {child!r} is the child of two joints "
                             f"({parent_of[child][0].name if parent_of[child][0] else '?'}, {name}); "
                             "the model is not a tree (a closed or parallel chain)")
        parent_of[child] = (joint, kind, parent)
    if frame is None:
        leaves = [n for n in links if n not in {p for _, _, p in parent_of.values()}]
        if len(leaves) != 1:
            raise InputError(f"{source}: choose the frame; its end links are {', '.join(map(str, leaves))}")
        frame = str(leaves[0])
    if frame not in links:
        raise InputError(f"{source}: frame {frame!r} is not a link (links: {', '.join(map(str, links))})")
    if base is not None and base not in links:
        raise InputError(f"{source}: base {base!r} is not a link (links: {', '.join(map(str, links))})")
    path: list[Joint] = []
    seen, link = {frame}, frame
    while link != base and link in parent_of:
        joint, kind, parent = parent_of[link]
        if parent in seen:
            raise InputError(f"{source}: the joints above link {frame!r} form a loop through link {parent!r}")
        if joint is None:
            raise InputError(f"{source}: joint between {parent!r} and {link!r} is {kind}; a chain "
                             f"from base to frame supports {', '.join(JOINT_TYPES)} joints "
                             "(choose a base below it)")
        path.append(joint)
        seen.add(parent)
        link = parent
    if base is not None and link != base:
        raise InputError(f"{source}: frame {frame!r} is not below base {base!r} (its root link is {link!r})")
    return Chain(tuple(reversed(path)), base=link, frame=frame, source=source)


def parse_urdf(text: str | bytes, frame: str | None = None, base: str | None = None,
               source: str = "URDF") -> Chain:
    """The chain from ``base`` (default: the root link) to the link ``frame`` (default: the only
    end link) of URDF text."""
    return urdf_chain(parse_xml(text, source), frame, base, source)


def read_urdf(path: str | Path, frame: str | None = None, base: str | None = None) -> Chain:
    """The chain from ``base`` (default: the root link) to the link ``frame`` (default: the only
    end link) of a URDF file."""
    return urdf_chain(read_xml(path), frame, base, str(path))
