"""Rigid transforms of the robot models: 4×4 homogeneous matrices, URDF's roll–pitch–yaw,
rotations about an axis (Rodrigues), and unit quaternions.

Conventions (those of URDF and of ALGORITHMS.md §7):

* a transform T = [[R, p], [0, 1]] maps coordinates in the child frame to the parent frame;
* URDF ``rpy = (r, p, y)`` is R = R_z(y) R_y(p) R_x(r) (fixed axes x, y, z in that order);
* a rotation by angle q about the unit axis a is R = I + sin q [a]× + (1 − cos q) [a]×²;
* a quaternion is (w, x, y, z) with w ≥ 0.
"""

from __future__ import annotations

import numpy as np


def rot_x(angle: float) -> np.ndarray:
    """Rotation about x by ``angle`` radians (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[1.0, 0.0, 0.0], [0.0, c, -s], [0.0, s, c]])


def rot_y(angle: float) -> np.ndarray:
    """Rotation about y by ``angle`` radians (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, 0.0, s], [0.0, 1.0, 0.0], [-s, 0.0, c]])


def rot_z(angle: float) -> np.ndarray:
    """Rotation about z by ``angle`` radians (3, 3)."""
    c, s = np.cos(angle), np.sin(angle)
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]])


def homogeneous(R: np.ndarray | None = None, p: np.ndarray | None = None) -> np.ndarray:
    """[[R, p], [0, 1]] (4, 4) from a rotation (3, 3) and a translation (3,); identity parts by default."""
    T = np.eye(4)
    if R is not None:
        T[:3, :3] = R
    if p is not None:
        T[:3, 3] = p
    return T


def translation(x: float = 0.0, y: float = 0.0, z: float = 0.0) -> np.ndarray:
    """Pure translation (4, 4)."""
    return homogeneous(p=np.array([x, y, z], dtype=float))


def rpy_matrix(rpy: np.ndarray) -> np.ndarray:
    """URDF roll–pitch–yaw (3,) → R = R_z(y) R_y(p) R_x(r) (3, 3)."""
    r, p, y = (float(v) for v in rpy)
    return rot_z(y) @ rot_y(p) @ rot_x(r)


def matrix_rpy(R: np.ndarray) -> np.ndarray:
    """Inverse of :func:`rpy_matrix`: R (3, 3) → (roll, pitch, yaw) with pitch in [−π/2, π/2].

    At pitch = ±π/2 (gimbal lock) only roll ∓ yaw is defined; yaw is set to 0 there.
    """
    pitch = np.arctan2(-R[2, 0], np.hypot(R[0, 0], R[1, 0]))
    if np.hypot(R[0, 0], R[1, 0]) < 1e-12:
        return np.array([np.arctan2(-R[1, 2], R[1, 1]), pitch, 0.0])
    return np.array([np.arctan2(R[2, 1], R[2, 2]), pitch, np.arctan2(R[1, 0], R[0, 0])])


def origin_matrix(xyz: np.ndarray, rpy: np.ndarray) -> np.ndarray:
    """A URDF ``<origin xyz rpy>`` as a transform (4, 4)."""
    return homogeneous(rpy_matrix(rpy), np.asarray(xyz, dtype=float))


def skew(a: np.ndarray) -> np.ndarray:
    """[a]× (3, 3): [a]× b = a × b."""
    x, y, z = (float(v) for v in a)
    return np.array([[0.0, -z, y], [z, 0.0, -x], [-y, x, 0.0]])


def z_to_axis(axis: np.ndarray) -> np.ndarray:
    """A rotation S (3, 3) with S e_z = a for the unit vector a (3,): the rotation about e_z × a
    by the angle between them; a rotation by π about x when a = −e_z."""
    a = np.asarray(axis, dtype=float)
    v, cos = np.cross([0.0, 0.0, 1.0], a), float(a[2])
    if cos < -1.0 + 1e-12:
        return rot_x(np.pi)
    K = skew(v)
    return np.eye(3) + K + (K @ K) / (1.0 + cos)


def axis_angle_matrices(axis: np.ndarray, angles: np.ndarray) -> np.ndarray:
    """Rotations by ``angles`` (N,) about one unit ``axis`` (3,): I + sin q [a]× + (1 − cos q) [a]×²
    → (N, 3, 3)."""
    K = skew(axis)
    q = np.asarray(angles, dtype=float)[:, None, None]
    return np.eye(3) + np.sin(q) * K + (1.0 - np.cos(q)) * (K @ K)


def quaternions(R: np.ndarray) -> np.ndarray:
    """Unit quaternions (w, x, y, z), w ≥ 0, of rotations R (N, 3, 3) → (N, 4).

    Each row is taken from the largest of 1 + tr R, 1 + 2R_xx − tr R, … (the well-conditioned
    branch of the Shepperd method), so no branch divides by a small number.
    """
    R = np.asarray(R, dtype=float)
    tr = np.trace(R, axis1=1, axis2=2)
    # 4 w², 4 x², 4 y², 4 z² from the trace and the diagonal
    sq = np.stack([1 + tr, 1 + 2 * R[:, 0, 0] - tr, 1 + 2 * R[:, 1, 1] - tr, 1 + 2 * R[:, 2, 2] - tr], 1)
    k = np.argmax(sq, 1)
    big = np.sqrt(np.maximum(sq[np.arange(len(R)), k], 0.0))  # 2 |component k|
    # 4 w x, 4 w y, 4 w z, 4 x y, 4 x z, 4 y z from the off-diagonal entries
    wx, wy, wz = R[:, 2, 1] - R[:, 1, 2], R[:, 0, 2] - R[:, 2, 0], R[:, 1, 0] - R[:, 0, 1]
    xy, xz, yz = R[:, 0, 1] + R[:, 1, 0], R[:, 0, 2] + R[:, 2, 0], R[:, 1, 2] + R[:, 2, 1]
    rows = np.stack([
        np.stack([sq[:, 0], wx, wy, wz], 1),
        np.stack([wx, sq[:, 1], xy, xz], 1),
        np.stack([wy, xy, sq[:, 2], yz], 1),
        np.stack([wz, xz, yz, sq[:, 3]], 1),
    ], 1)  # (N, branch, 4): 4 q_k q
    out = rows[np.arange(len(R)), k] / (2.0 * big[:, None])
    out *= np.where(out[:, :1] < 0, -1.0, 1.0)
    return out


def quaternion_matrix(q: np.ndarray) -> np.ndarray:
    """Unit quaternion (w, x, y, z) (4,) → rotation (3, 3) (normalised first)."""
    w, x, y, z = np.asarray(q, dtype=float) / np.linalg.norm(q)
    return np.array([[1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)],
                     [2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)],
                     [2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)]])
