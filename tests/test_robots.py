"""Robot models (ccl_cli.learn.robots): URDF / DH → chains, batched FK and geometric Jacobians.

References are computed independently of the library: the DH link matrices written out here,
SciPy's rotations for URDF origins and joint motions, and central finite differences of the
forward kinematics for both the linear and the angular rows of the Jacobian.
"""

from __future__ import annotations

import numpy as np
import pytest
from scipy.spatial.transform import Rotation

from ccl_cli.errors import CCLError, ConfigError, InputError
from ccl_cli.learn.kinematics import SevenDofArm
from ccl_cli.learn.robots import (
    LWR4,
    PANDA,
    Chain,
    chain_urdf,
    dh_chain,
    dh_urdf,
    load_robot,
    match_joints,
    parse_urdf,
    quaternions,
    read_urdf,
    robot_features,
)
from ccl_cli.learn.robots.transforms import matrix_rpy, rpy_matrix

RNG = np.random.default_rng(18)


def within_limits(chain: Chain, n: int) -> np.ndarray:
    return RNG.uniform(chain.lower, chain.upper, (n, chain.n_joints))


# --- independent references ------------------------------------------------------------------

def dh_standard(table: np.ndarray, q: np.ndarray) -> np.ndarray:
    """ᶦ⁻¹T_i = R_z(θ) T_z(d) T_x(a) R_x(α), written out (Spong, Hutchinson, Vidyasagar, eq. 3.10)."""
    T = np.eye(4)
    for (a, d, alpha, theta0), qi in zip(table, q, strict=True):
        ct, st, ca, sa = np.cos(theta0 + qi), np.sin(theta0 + qi), np.cos(alpha), np.sin(alpha)
        T = T @ np.array([[ct, -st * ca, st * sa, a * ct], [st, ct * ca, -ct * sa, a * st],
                          [0, sa, ca, d], [0, 0, 0, 1]])
    return T


def dh_modified(table: np.ndarray, q: np.ndarray, tip_z: float) -> np.ndarray:
    """ᶦ⁻¹T_i = R_x(α_{i−1}) T_x(a_{i−1}) R_z(θ_i) T_z(d_i), written out (Craig, eq. 3.6)."""
    T = np.eye(4)
    for (a, d, alpha, theta0), qi in zip(table, q, strict=True):
        ct, st, ca, sa = np.cos(theta0 + qi), np.sin(theta0 + qi), np.cos(alpha), np.sin(alpha)
        T = T @ np.array([[ct, -st, 0, a], [st * ca, ct * ca, -sa, -sa * d],
                          [st * sa, ct * sa, ca, ca * d], [0, 0, 0, 1]])
    return T @ np.array([[1, 0, 0, 0], [0, 1, 0, 0], [0, 0, 1, tip_z], [0, 0, 0, 1.0]])


def finite_difference_jacobian(chain: Chain, q: np.ndarray, h: float = 1e-6) -> np.ndarray:
    """(6, n): linear rows ∂p/∂q_j; angular rows ω_j from R(q + h e_j) R(q − h e_j)ᵀ ≈ exp(2h [ω_j]×)."""
    n = chain.n_joints
    Q = np.vstack([q + h * np.eye(n), q - h * np.eye(n)])
    pose = chain.forward(Q)
    J = np.empty((6, n))
    J[:3] = ((pose.position[:n] - pose.position[n:]) / (2 * h)).T
    M = pose.rotation[:n] @ pose.rotation[n:].transpose(0, 2, 1)
    W = (M - M.transpose(0, 2, 1)) / (4 * h)  # [ω]× to O(h²)
    J[3:] = np.stack([W[:, 2, 1], W[:, 0, 2], W[:, 1, 0]])
    return J


# --- DH tables --------------------------------------------------------------------------------

def test_dh_table_reproduces_seven_dof_arm():
    arm = SevenDofArm()
    chain = dh_chain(np.c_[arm.a, arm.d, arm.alpha, np.zeros(7)])
    Q = RNG.uniform(-np.pi, np.pi, (500, 7))
    np.testing.assert_allclose(chain.jacobian(Q), arm.jacobian(Q), rtol=0, atol=1e-12)
    np.testing.assert_allclose(chain.forward(Q).position, arm.forward(Q), rtol=0, atol=1e-12)
    np.testing.assert_allclose(chain.forward(Q).rotation, arm.frames(Q)[:, 7, :3, :3], rtol=0, atol=1e-12)


@pytest.mark.parametrize("robot", [LWR4, PANDA], ids=["lwr4+", "panda"])
def test_published_urdf_fk_matches_dh_formulas(robot, tmp_path):
    path = tmp_path / f"{robot.name}.urdf"
    path.write_text(robot.urdf())
    chain = read_urdf(path, robot.frame)
    assert chain.joint_names == list(robot.joint_names)
    np.testing.assert_allclose(np.c_[chain.lower, chain.upper], robot.limits)
    Q = within_limits(chain, 200)
    pose = chain.forward(Q)
    table = np.asarray(robot.table)
    for q, p, R in zip(Q, pose.position, pose.rotation, strict=True):
        T = dh_modified(table, q, robot.tip_z) if robot.modified else dh_standard(table, q)
        np.testing.assert_allclose(p, T[:3, 3], rtol=0, atol=1e-12)
        np.testing.assert_allclose(R, T[:3, :3], rtol=0, atol=1e-12)


def test_published_zero_postures():
    """At q = 0 the LWR 4+ stands straight up (0.3105 + 0.4 + 0.39 + 0.078 m) and the Panda's
    flange is at (0.088, 0, 0.333 + 0.316 + 0.384 − 0.107) m, pointing down."""
    lwr = LWR4.chain().forward(np.zeros((1, 7)))
    np.testing.assert_allclose(lwr.position[0], [0, 0, 1.1785], atol=1e-12)
    np.testing.assert_allclose(lwr.rotation[0], np.eye(3), atol=1e-12)
    panda = parse_urdf(PANDA.urdf(), "panda_link8").forward(np.zeros((1, 7)))
    np.testing.assert_allclose(panda.position[0], [0.088, 0, 0.926], atol=1e-12)
    np.testing.assert_allclose(panda.rotation[0], np.diag([1.0, -1.0, -1.0]), atol=1e-12)


@pytest.mark.parametrize("robot", [LWR4, PANDA], ids=["lwr4+", "panda"])
def test_jacobian_matches_finite_differences(robot):
    chain = parse_urdf(robot.urdf(), robot.frame)
    Q = within_limits(chain, 20)
    J = chain.jacobian(Q)
    for q, Jq in zip(Q, J, strict=True):
        np.testing.assert_allclose(Jq, finite_difference_jacobian(chain, q), rtol=0, atol=1e-8)


def test_prismatic_dh_joint():
    """A Cartesian-style R-P chain: d₂ grows with q₂; the Jacobian column is the slide axis."""
    table = [[0.0, 0.5, np.pi / 2, 0.0], [0.0, 0.2, 0.0, 0.0]]
    chain = dh_chain(table, types="RP")
    Q = np.array([[0.3, 0.4], [-1.0, 0.0]])
    for q, p in zip(Q, chain.forward(Q).position, strict=True):
        ref = dh_standard(np.array([[0.0, 0.5, np.pi / 2, 0.0], [0.0, 0.2 + q[1], 0.0, 0.0]]), [q[0], 0.0])
        np.testing.assert_allclose(p, ref[:3, 3], atol=1e-12)
    for q in Q:
        np.testing.assert_allclose(chain.jacobian(q[None])[0], finite_difference_jacobian(chain, q),
                                   atol=1e-8)
    assert np.all(chain.jacobian(Q)[:, 3:, 1] == 0)


def test_theta_offsets_and_modified_flag_change_the_chain():
    table = np.asarray(PANDA.table)
    shifted = table.copy()
    shifted[:, 3] = RNG.uniform(-1, 1, 7)
    q = RNG.uniform(-1, 1, 7)
    chain = dh_chain(shifted, modified=True, tip=np.diag([1, 1, 1, 1.0]))
    modified = dh_modified(shifted, q, 0.0)[:3, 3]
    np.testing.assert_allclose(chain.forward(q[None]).position[0], modified, atol=1e-12)
    standard = dh_chain(shifted).forward(q[None]).position[0]
    np.testing.assert_allclose(standard, dh_standard(shifted, q)[:3, 3], atol=1e-12)
    assert np.linalg.norm(standard - modified) > 1e-2


# --- URDF with origins, branches, prismatic and fixed joints -----------------------------------

BRANCHED = """<?xml version="1.0"?>
<robot name="branched">
  <link name="world"/> <link name="base"/> <link name="l1"/> <link name="l2"/> <link name="l3"/>
  <link name="tool"/> <link name="camera"/> <link name="finger"/>
  <joint name="mount" type="fixed"><parent link="world"/><child link="base"/>
    <origin xyz="0.1 -0.2 0.05" rpy="0.3 -0.2 1.1"/></joint>
  <joint name="j1" type="revolute"><parent link="base"/><child link="l1"/>
    <origin xyz="0 0 0.3" rpy="0 0 0"/><axis xyz="0 0 1"/>
    <limit lower="-2" upper="2" effort="1" velocity="1"/></joint>
  <joint name="j2" type="continuous"><parent link="l1"/><child link="l2"/>
    <origin xyz="0.2 0.1 0" rpy="1.2 0.4 -0.7"/><axis xyz="1 2 -0.5"/></joint>
  <joint name="slide" type="prismatic"><parent link="l2"/><child link="l3"/>
    <origin xyz="0.4 0 0.1" rpy="-0.5 0.9 0.2"/><axis xyz="0 1 1"/>
    <limit lower="0" upper="0.3" effort="1" velocity="1"/></joint>
  <joint name="j4" type="revolute"><parent link="l3"/><child link="tool"/>
    <origin xyz="0.05 0.02 0.25" rpy="0.1 0.2 0.3"/><axis xyz="0 -1 0"/>
    <limit lower="-1" upper="1" effort="1" velocity="1"/></joint>
  <joint name="cam" type="fixed"><parent link="l1"/><child link="camera"/><origin xyz="0 0.5 0"/></joint>
  <joint name="grip" type="prismatic"><parent link="tool"/><child link="finger"/>
    <axis xyz="1 0 0"/><limit lower="0" upper="0.04" effort="1" velocity="1"/></joint>
</robot>
"""

#: (origin xyz, rpy, axis, type) of world → tool, the reference for BRANCHED
PATH = [((0.1, -0.2, 0.05), (0.3, -0.2, 1.1), None, "fixed"),
        ((0, 0, 0.3), (0, 0, 0), (0, 0, 1), "revolute"),
        ((0.2, 0.1, 0), (1.2, 0.4, -0.7), (1, 2, -0.5), "revolute"),
        ((0.4, 0, 0.1), (-0.5, 0.9, 0.2), (0, 1, 1), "prismatic"),
        ((0.05, 0.02, 0.25), (0.1, 0.2, 0.3), (0, -1, 0), "revolute")]


def reference_pose(q: np.ndarray) -> np.ndarray:
    """world → tool by SciPy: URDF rpy is extrinsic x-y-z; a joint moves about/along its axis."""
    T, k = np.eye(4), 0
    for xyz, rpy, axis, kind in PATH:
        O = np.eye(4)
        O[:3, :3], O[:3, 3] = Rotation.from_euler("xyz", rpy).as_matrix(), xyz
        M = np.eye(4)
        if kind != "fixed":
            u = np.asarray(axis, float) / np.linalg.norm(axis)
            if kind == "revolute":
                M[:3, :3] = Rotation.from_rotvec(u * q[k]).as_matrix()
            else:
                M[:3, 3] = u * q[k]
            k += 1
        T = T @ O @ M
    return T


def test_branched_urdf_chain_follows_the_path_to_the_frame():
    chain = parse_urdf(BRANCHED, "tool")
    assert (chain.base, chain.frame) == ("world", "tool")
    assert [j.name for j in chain.joints] == ["mount", "j1", "j2", "slide", "j4"]
    assert chain.joint_names == ["j1", "j2", "slide", "j4"]
    assert [j.type for j in chain.moving] == ["revolute", "continuous", "prismatic", "revolute"]
    np.testing.assert_allclose(chain.lower, [-2, -np.inf, 0, -1])
    Q = RNG.uniform([-2, -3, 0, -1], [2, 3, 0.3, 1], (100, 4))
    pose = chain.forward(Q)
    for q, p, R in zip(Q, pose.position, pose.rotation, strict=True):
        T = reference_pose(q)
        np.testing.assert_allclose(p, T[:3, 3], atol=1e-12)
        np.testing.assert_allclose(R, T[:3, :3], atol=1e-12)
    for q in Q[:10]:
        np.testing.assert_allclose(chain.jacobian(q[None])[0], finite_difference_jacobian(chain, q),
                                   atol=1e-8)
    assert parse_urdf(BRANCHED, "finger").joint_names[-1] == "grip"
    sub = parse_urdf(BRANCHED, "tool", base="l1")
    assert sub.joint_names == ["j2", "slide", "j4"]


def test_chain_to_urdf_round_trip():
    chain = parse_urdf(BRANCHED, "tool")
    again = parse_urdf(chain_urdf(chain), "tool")
    assert again.joint_names == chain.joint_names
    Q = RNG.uniform([-2, -3, 0, -1], [2, 3, 0.3, 1], (300, 4))
    np.testing.assert_allclose(again.jacobian(Q), chain.jacobian(Q), atol=1e-12)


def test_rows_and_chunks():
    chain = LWR4.chain()
    Q = within_limits(chain, 1001)
    pose, J = chain.forward_jacobian(Q)
    np.testing.assert_allclose(chain.jacobian(Q, chunk=7), J, rtol=0, atol=0)
    np.testing.assert_allclose(chain.forward(Q, chunk=100).position, pose.position, rtol=0, atol=0)
    np.testing.assert_array_equal(chain.jacobian(Q, rows=[2, 5]), J[:, [2, 5]])
    np.testing.assert_array_equal(chain.jacobian(Q[0]), J[:1])
    with pytest.raises(InputError, match="rows"):
        chain.jacobian(Q, rows=[6])


def test_rotations_helpers_against_scipy():
    R = Rotation.random(500, random_state=3).as_matrix()
    quat = quaternions(R)
    ref = Rotation.from_matrix(R).as_quat()[:, [3, 0, 1, 2]]
    ref *= np.sign(ref[:, :1])
    np.testing.assert_allclose(quat, ref, atol=1e-12)
    for rpy in RNG.uniform(-3, 3, (50, 3)):
        R1 = rpy_matrix(rpy)
        np.testing.assert_allclose(R1, Rotation.from_euler("xyz", rpy).as_matrix(), atol=1e-12)
        np.testing.assert_allclose(rpy_matrix(matrix_rpy(R1)), R1, atol=1e-12)
    lock = rpy_matrix([0.4, np.pi / 2, 0.0])
    np.testing.assert_allclose(rpy_matrix(matrix_rpy(lock)), lock, atol=1e-12)


# --- known features of the lambda constraint ---------------------------------------------------

def test_robot_features_equal_arm7_in_the_lambda_learner(tmp_path):
    """The issue's bar: lambda with the arm7 chain given as a URDF learns the same N(q) as the
    built-in ``arm7`` features."""
    from ccl_cli.learn import KnownFeatureConstraint
    from ccl_cli.learn.kinematics import ArmFeatures
    from ccl_cli.learn.linalg import nullspace_projection
    from ccl_cli.simulate.reference import arm7

    arm = SevenDofArm()
    path = tmp_path / "arm7.urdf"
    path.write_text(dh_urdf(np.c_[arm.a, arm.d, arm.alpha, np.zeros(7)]))
    features = robot_features({"robot": str(path), "rows": [0, 1, 2]})
    data = arm7(rows=(0, 1, 2), constraint="jacobian", n_demos=10, n_steps=20, seed=1)
    np.testing.assert_allclose(features(data.X), ArmFeatures("arm7", [0, 1, 2])(data.X), rtol=0, atol=1e-12)
    fits = [KnownFeatureConstraint(features=f, tune=False, n_centres=1).fit(data.X, data.U, groups=data.demo)
            for f in ({"arm": "arm7", "rows": [0, 1, 2]}, features)]
    N = [nullspace_projection(m.constraint(data.X)) for m in fits]
    assert fits[0].n_constraints_ == fits[1].n_constraints_
    assert np.abs(N[0] - N[1]).max() < 1e-9


def test_robot_features_spec_holds_the_chain(tmp_path):
    path = tmp_path / "panda.urdf"
    path.write_text(PANDA.urdf())
    features = robot_features({"robot": str(path), "frame": "panda_link8", "rows": [2, 3, 4]})
    spec = features.spec()
    path.unlink()  # the stored form does not need the file
    again = robot_features(spec)
    Q = within_limits(features.chain, 200)
    np.testing.assert_allclose(again(Q), features(Q), rtol=0, atol=1e-12)
    assert again(Q).shape == (200, 3, 7)
    with pytest.raises(ConfigError, match="rows"):
        robot_features({"urdf": spec["urdf"], "rows": [7]})
    with pytest.raises(ConfigError, match="unknown: row"):
        robot_features({"urdf": spec["urdf"], "row": [1]})


# --- joint names ------------------------------------------------------------------------------

def test_match_joints_order_and_prefixes():
    chain = list(PANDA.joint_names)
    log = [chain[i] for i in (3, 0, 6, 1, 5, 2, 4)]
    idx = match_joints(log, chain)
    assert [log[i] for i in idx] == chain
    short = [s.removeprefix("panda_") for s in log]
    assert [short[i] for i in match_joints(short, chain)] == [s.removeprefix("panda_") for s in chain]
    namespaced = ["/arm/" + s for s in log] + ["/arm/panda_finger_joint1"]
    idx = match_joints(namespaced, chain, allow_extra=True)
    assert [namespaced[i] for i in idx] == ["/arm/" + s for s in chain]
    Q_log = RNG.normal(size=(5, 8))
    np.testing.assert_array_equal(Q_log[:, idx][:, 0], Q_log[:, namespaced.index("/arm/panda_joint1")])


def test_match_joints_errors_name_the_joints():
    chain = list(PANDA.joint_names)
    with pytest.raises(InputError, match="missing from the log: panda_joint7") as e:
        match_joints(chain[:6], chain)
    assert "\n" not in str(e.value)
    with pytest.raises(InputError, match="not in the robot: panda_finger_joint1"):
        match_joints([*chain, "panda_finger_joint1"], chain)
    with pytest.raises(InputError, match="repeated in the log: panda_joint1"):
        match_joints([*chain, "panda_joint1"], chain)


# --- loading and bad input --------------------------------------------------------------------

def test_load_robot(tmp_path):
    path = tmp_path / "lwr.urdf"
    path.write_text(LWR4.urdf())
    chain = load_robot(str(path))  # the only end link is the frame
    assert chain.frame == "flange" and chain.joint_names == list(LWR4.joint_names)
    dh = load_robot({"dh": [list(r) for r in LWR4.table], "tip": {"xyz": [0, 0, 0.1]}}, frame="tool")
    Q = within_limits(chain, 50)
    lifted = chain.forward(Q)
    expected = lifted.position + 0.1 * lifted.rotation[:, :, 2]
    np.testing.assert_allclose(dh.forward(Q).position, expected, atol=1e-12)
    with pytest.raises(ConfigError, match="unknown: dhh"):
        load_robot({"dh": [[0, 0, 0, 0]], "dhh": 1})
    with pytest.raises(ConfigError, match=r"a \.urdf or MJCF \.xml file"):
        load_robot(str(tmp_path / "arm.sdf"))
    with pytest.raises(InputError, match="cannot read"):
        load_robot(str(tmp_path / "missing.urdf"))
    as_xml = tmp_path / "lwr.xml"  # a URDF is known by its <robot> root whatever its suffix
    as_xml.write_text(LWR4.urdf())
    np.testing.assert_array_equal(load_robot(str(as_xml)).jacobian(Q), chain.jacobian(Q))
    other = tmp_path / "scene.xml"
    other.write_text("<sdf/>")
    with pytest.raises(InputError, match="neither URDF"):
        load_robot(str(other))
    with pytest.raises(InputError, match="DH table"):
        dh_chain([[0, 0, 0]])


def urdf(joints: str, links: str = "a b c") -> str:
    body = " ".join(f'<link name="{n}"/>' for n in links.split())
    return f'<robot name="r">{body}{joints}</robot>'


def joint(name: str, parent: str, child: str, kind: str = "revolute", extra: str = "") -> str:
    return (f'<joint name="{name}" type="{kind}"><parent link="{parent}"/><child link="{child}"/>'
            f'<axis xyz="0 0 1"/>{extra}</joint>')


BAD = {
    "missing frame": (urdf(joint("j1", "a", "b")), "frame 'tool' is not a link"),
    "loop": (urdf(joint("j1", "a", "b") + joint("j2", "b", "c") + joint("j3", "c", "a")), "loop"),
    "two parents": (urdf(joint("j1", "a", "c") + joint("j2", "b", "c")), "child of two joints"),
    "unknown type": (urdf(joint("j1", "a", "b", "hinge")), "type 'hinge'"),
    "floating on chain": (urdf(joint("j1", "a", "b", "floating")), "is floating"),
    "undefined link": (urdf(joint("j1", "a", "z")), "link 'z', which is not defined"),
    "bad origin": (urdf(joint("j1", "a", "b", extra='<origin xyz="0 0"/>')), "origin xyz"),
    "zero axis": (urdf('<joint name="j1" type="revolute"><parent link="a"/><child link="b"/>'
                       '<axis xyz="0 0 0"/></joint>'), "zero length"),
    "mimic": (urdf(joint("j1", "a", "b", extra='<mimic joint="j0"/>')), "mimics"),
    "not a urdf": ('<mujoco model="m"><worldbody/></mujoco>', "not a URDF"),
    "xacro": ('<robot xmlns:xacro="http://www.ros.org/wiki/xacro"><xacro:property name="l" value="1"/>'
              '</robot>', "xacro"),
    "malformed": ('<robot name="r"><link name="a"></robot>',
                  r"not well-formed XML \(mismatched tag at line 1"),
    "entity expansion": ('<?xml version="1.0"?><!DOCTYPE lolz [<!ENTITY lol "lol">'
                         '<!ENTITY lol2 "&lol;&lol;&lol;&lol;&lol;&lol;&lol;&lol;">]>'
                         '<robot name="&lol2;"><link name="a"/></robot>', "document type"),
    "external entity": ('<?xml version="1.0"?><!DOCTYPE r [<!ENTITY x SYSTEM "file:///etc/passwd">]>'
                        '<robot name="r">&x;</robot>', "document type"),
    "undeclared entity": ('<robot name="&x;"/>', "undefined entity"),
}


@pytest.mark.parametrize("case", sorted(BAD))
def test_bad_urdf_gives_one_clear_line(case, tmp_path):
    text, message = BAD[case]
    path = tmp_path / "bad.urdf"
    path.write_text(text)
    frame = "tool" if case == "missing frame" else ("c" if case != "floating on chain" else "b")
    with pytest.raises(InputError, match=message) as e:
        read_urdf(path, frame)
    assert "\n" not in str(e.value) and str(path) in str(e.value)


def test_non_serial_base_and_frame_choice():
    text = urdf(joint("j1", "a", "b") + joint("j2", "a", "c"))
    with pytest.raises(InputError, match="not below base 'b'"):
        parse_urdf(text, "c", base="b")
    with pytest.raises(InputError, match="choose the frame; its end links are b, c"):
        parse_urdf(text)
    with pytest.raises(InputError, match=r"needs \(N, 1\) with columns j1"):
        parse_urdf(text, "b").forward(np.zeros((3, 2)))


def test_urdf_writer_keeps_prismatic_limits_finite():
    with pytest.raises(CCLError, match="finite limits"):
        dh_urdf([[0, 0, 0, 0]], types="P")
    text = dh_urdf([[0, 0, 0, 0]], types="P", limits=[[0, 0.5]])
    assert parse_urdf(text).moving[0].type == "prismatic"


# --- MJCF (read by MuJoCo, the robots extra) ----------------------------------------------------

ARM_MJCF = """<mujoco model="arm">
  <compiler angle="degree"/>
  <default><joint range="-150 150" limited="true"/></default>
  <worldbody>
    <body name="base" pos="0.1 0.2 0.3" euler="10 -20 30">
      <joint name="yaw" type="hinge" axis="0 0 1" pos="0 0.05 0" ref="15"/>
      <geom size="0.05"/>
      <body name="upper" pos="0 0 0.4" quat="0.9 0.3 -0.2 0.1">
        <joint name="pitch" type="hinge" axis="0 1 0.3" pos="0.02 0 -0.1"/>
        <joint name="roll" type="hinge" axis="1 0 0" limited="false"/>
        <geom size="0.05"/>
        <body name="fore" pos="0.35 0 0" axisangle="0 0 1 40">
          <joint name="slide" type="slide" axis="1 1 0" range="0 0.2" ref="0.05"/>
          <geom size="0.04"/>
          <site name="tool" pos="0.1 0 0.03" euler="0 90 0"/>
        </body>
      </body>
      <body name="camera" pos="0 0.3 0"><joint name="pan" axis="0 0 1"/><geom size="0.02"/></body>
    </body>
    <body name="table" pos="1 0 0"><freejoint name="free"/><geom size="0.1"/></body>
  </worldbody>
</mujoco>
"""


def test_mjcf_chain_matches_mujoco(tmp_path):
    mujoco = pytest.importorskip("mujoco")
    path = tmp_path / "arm.xml"
    path.write_text(ARM_MJCF)
    chain = load_robot(str(path), frame="tool")
    assert chain.joint_names == ["yaw", "pitch", "roll", "slide"]
    assert [j.type for j in chain.moving] == ["revolute", "revolute", "continuous", "prismatic"]
    np.testing.assert_allclose(chain.lower, np.deg2rad([-150, -150, -np.inf, 0]) + [0, 0, 0, 0])
    model = mujoco.MjModel.from_xml_path(str(path))
    data = mujoco.MjData(model)
    site = mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_SITE, "tool")
    ids = [mujoco.mj_name2id(model, mujoco.mjtObj.mjOBJ_JOINT, n) for n in chain.joint_names]
    cols, adr = model.jnt_dofadr[ids], model.jnt_qposadr[ids]
    Q = RNG.uniform([-2, -2, -3, 0], [2, 2, 3, 0.2], (30, 4))
    pose, J = chain.forward_jacobian(Q)
    jacp, jacr = np.zeros((3, model.nv)), np.zeros((3, model.nv))
    for q, p, R, Jq in zip(Q, pose.position, pose.rotation, J, strict=True):
        data.qpos[:] = model.qpos0
        data.qpos[adr] = q
        mujoco.mj_forward(model, data)
        mujoco.mj_jacSite(model, data, jacp, jacr, site)
        np.testing.assert_allclose(p, data.site_xpos[site], atol=1e-12)
        np.testing.assert_allclose(R, data.site_xmat[site].reshape(3, 3), atol=1e-12)
        np.testing.assert_allclose(Jq, np.vstack([jacp[:, cols], jacr[:, cols]]), atol=1e-12)
    assert load_robot(str(path), frame="fore", base="upper").joint_names == ["slide"]
    with pytest.raises(InputError, match="'nowhere' is neither a site nor a body"):
        load_robot(str(path), frame="nowhere")
    with pytest.raises(InputError, match="'free' of body 'table' is a free joint"):
        load_robot(str(path), frame="table")
    bad = tmp_path / "bad.xml"
    bad.write_text(ARM_MJCF.replace('<geom size="0.04"/>', '<geom type="mesh" mesh="missing"/>'))
    with pytest.raises(InputError, match="MuJoCo cannot load it") as e:
        load_robot(str(bad), frame="tool")
    assert "\n" not in str(e.value)


def test_mjcf_without_mujoco_names_the_extra(tmp_path, monkeypatch):
    import sys

    path = tmp_path / "arm.xml"
    path.write_text(ARM_MJCF)
    monkeypatch.setitem(sys.modules, "mujoco", None)
    with pytest.raises(ConfigError, match=r"pip install 'ccl_cli\[robots\]'"):
        load_robot(str(path), frame="tool")
    with pytest.raises(ConfigError, match="give frame"):
        load_robot(str(path))


def test_features_robot_through_the_command_line_and_a_saved_model(capsys, tmp_path):
    """``features: {robot: arm.urdf, rows: [...]}`` in a config: lambda learns the same N(q) as
    ``features: arm7`` (max |ΔN| < 1e-9), the model file holds the chain itself (it loads and
    predicts with the URDF file gone), and linear takes the robot's Jacobian rows as regressors."""
    from ccl_cli.cli import main
    from ccl_cli.io import write_demonstrations
    from ccl_cli.models import load_model
    from ccl_cli.simulate.reference import arm7

    arm = SevenDofArm()
    urdf = tmp_path / "arm7.urdf"
    urdf.write_text(dh_urdf(np.c_[arm.a, arm.d, arm.alpha, np.zeros(7)]))
    data = arm7(rows=(0, 1, 2), constraint="jacobian", n_demos=10, n_steps=20, seed=2)
    path = write_demonstrations(tmp_path / "arm.h5", data)
    models = {}
    specs = (("urdf", f"{{robot: {urdf}, rows: [0, 1, 2]}}"), ("arm", "{arm: arm7, rows: [0, 1, 2]}"))
    for name, features in specs:
        cfg = tmp_path / f"{name}.yaml"
        cfg.write_text(f"learn-a: {{method: lambda, n_centres: 1, tune: false, features: {features}}}\n")
        assert main(["learn-a", str(path), "-c", str(cfg), "-o", str(tmp_path / name), "-q"]) == 0
        models[name] = tmp_path / name / "model.h5"
    urdf.unlink()  # the saved model holds the chain as URDF text
    robot, _ = load_model(models["urdf"])
    builtin, _ = load_model(models["arm"])
    assert np.abs(robot.projection(data.X) - builtin.projection(data.X)).max() < 1e-9
    assert robot.features["kind"] == "robot" and "<robot" in robot.features["urdf"]
    urdf.write_text(dh_urdf(np.c_[arm.a, arm.d, arm.alpha, np.zeros(7)]))
    cfg = tmp_path / "linear.yaml"
    cfg.write_text(f"learn-a: {{method: linear, regressors: {{robot: {urdf}, rows: [0, 1, 2]}}}}\n")
    assert main(["learn-a", str(path), "-c", str(cfg), "-o", str(tmp_path / "lin"), "-q"]) == 0
    linear, _ = load_model(tmp_path / "lin" / "model.h5")
    assert linear.W_.shape[1] == 3 and np.isfinite(linear.projection(data.X)).all()
