"""Batched rotation math on numpy arrays, used offline (clip generation, retargeting).

Quaternions are wxyz (MuJoCo's order). Matrices act on column vectors: v_world = R @ v_body.
Euler "xyz" means R = Rx(a) @ Ry(b) @ Rz(c), which is how MuJoCo composes the three hinges
x, y, z of one body (checked in tests/test_motion_retarget.py against mj_kinematics).
The torch counterparts used at training time live in `detach.torch_math`.
"""

from __future__ import annotations

import numpy as np

_EPS = 1e-9


def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Hamilton product a * b of wxyz quaternions [..., 4]."""
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack((
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ), axis=-1)


def quat_conj(q: np.ndarray) -> np.ndarray:
    return np.concatenate((q[..., :1], -q[..., 1:]), axis=-1)


def quat_normalize(q: np.ndarray) -> np.ndarray:
    return q / np.maximum(np.linalg.norm(q, axis=-1, keepdims=True), _EPS)


def quat_from_axis_angle(axis: np.ndarray, angle: np.ndarray) -> np.ndarray:
    """Rotation by `angle` radians [...] about unit `axis` [..., 3] (broadcast)."""
    axis = np.asarray(axis, dtype=np.float64)
    half = 0.5 * np.asarray(angle, dtype=np.float64)[..., None]
    return np.concatenate((np.cos(half) * np.ones_like(axis[..., :1]), np.sin(half) * axis), axis=-1)


def quat_from_yaw_pitch(yaw: np.ndarray, pitch: np.ndarray) -> np.ndarray:
    """Rz(yaw) @ Ry(pitch): heading about world +Z, then a forward lean (pitch > 0 tips +Z to +X)."""
    qz = quat_from_axis_angle(np.array([0.0, 0.0, 1.0]), yaw)
    qy = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), pitch)
    return quat_mul(qz, qy)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v [..., 3] by unit quaternions q [..., 4]."""
    w, xyz = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(xyz, v)
    return v + w * t + np.cross(xyz, t)


def quat_to_matrix(q: np.ndarray) -> np.ndarray:
    """[..., 4] wxyz -> [..., 3, 3]."""
    w, x, y, z = np.moveaxis(quat_normalize(q), -1, 0)
    return np.stack((
        np.stack((1 - 2 * (y * y + z * z), 2 * (x * y - w * z), 2 * (x * z + w * y)), -1),
        np.stack((2 * (x * y + w * z), 1 - 2 * (x * x + z * z), 2 * (y * z - w * x)), -1),
        np.stack((2 * (x * z - w * y), 2 * (y * z + w * x), 1 - 2 * (x * x + y * y)), -1),
    ), axis=-2)


def matrix_to_quat(m: np.ndarray) -> np.ndarray:
    """[..., 3, 3] rotation matrices -> [..., 4] wxyz with w >= 0 (numerically robust branch)."""
    m = np.asarray(m, dtype=np.float64)
    m00, m01, m02 = m[..., 0, 0], m[..., 0, 1], m[..., 0, 2]
    m10, m11, m12 = m[..., 1, 0], m[..., 1, 1], m[..., 1, 2]
    m20, m21, m22 = m[..., 2, 0], m[..., 2, 1], m[..., 2, 2]
    tr = m00 + m11 + m22
    cand = np.stack((  # row k is 4 * q_k * q (k = w, x, y, z); pick the row with the largest |q_k|
        np.stack((1 + tr, m21 - m12, m02 - m20, m10 - m01), -1),
        np.stack((m21 - m12, 1 + 2 * m00 - tr, m01 + m10, m02 + m20), -1),
        np.stack((m02 - m20, m01 + m10, 1 + 2 * m11 - tr, m12 + m21), -1),
        np.stack((m10 - m01, m02 + m20, m12 + m21, 1 + 2 * m22 - tr), -1),
    ), axis=-2)
    k = np.argmax(np.stack((1 + tr, 1 + 2 * m00 - tr, 1 + 2 * m11 - tr, 1 + 2 * m22 - tr), -1), axis=-1)
    q = np.take_along_axis(cand, k[..., None, None], axis=-2)[..., 0, :]
    q = quat_normalize(q)
    return np.where(q[..., :1] < 0, -q, q)


def matrix_from_euler_xyz(a: np.ndarray, b: np.ndarray, c: np.ndarray) -> np.ndarray:
    """Rx(a) @ Ry(b) @ Rz(c) [..., 3, 3]: the rotation of a body whose hinges x, y, z read a, b, c."""
    return _rx(a) @ _ry(b) @ _rz(c)


def euler_xyz_from_matrix(m: np.ndarray, gimbal_eps: float = 1e-6) -> np.ndarray:
    """Angles (a, b, c) [..., 3] with Rx(a) Ry(b) Rz(c) = m, b in [-pi/2, pi/2].

    At gimbal lock (b = +-pi/2) only a + c (or a - c) is defined; c is set to 0 there so the
    result is deterministic instead of amplifying float noise.
    """
    sb = np.clip(m[..., 0, 2], -1.0, 1.0)
    b = np.arcsin(sb)
    cb = np.sqrt(np.maximum(1.0 - sb * sb, 0.0))
    a = np.arctan2(-m[..., 1, 2], m[..., 2, 2])
    c = np.arctan2(-m[..., 0, 1], m[..., 0, 0])
    lock = cb < gimbal_eps
    a_lock = np.arctan2(m[..., 2, 1], m[..., 1, 1])
    return np.stack((np.where(lock, a_lock, a), b, np.where(lock, 0.0, c)), axis=-1)


def twist_angle(q: np.ndarray, axis: int) -> np.ndarray:
    """Angle [...] of the twist of q about body axis 0/1/2 (swing-twist decomposition).

    Used for hinge-like joints (knee, elbow): the best single-hinge angle for a rotation that
    may carry a little swing from noisy mocap.
    """
    return 2.0 * np.arctan2(q[..., 1 + axis], q[..., 0])


def min_rotation(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """Smallest rotation (wxyz) turning unit vector a [3] onto unit vector b [3]."""
    a = a / np.linalg.norm(a)
    b = b / np.linalg.norm(b)
    axis = np.cross(a, b)
    s, c = np.linalg.norm(axis), float(np.dot(a, b))
    if s < 1e-9:
        if c > 0:
            return np.array([1.0, 0.0, 0.0, 0.0])
        perp = np.cross(a, [1.0, 0.0, 0.0])  # opposite vectors: any perpendicular axis
        if np.linalg.norm(perp) < 1e-6:
            perp = np.cross(a, [0.0, 1.0, 0.0])
        return quat_from_axis_angle(perp / np.linalg.norm(perp), np.pi)
    return quat_from_axis_angle(axis / s, np.arctan2(s, c))


def quat_continuous(q: np.ndarray) -> np.ndarray:
    """Flip signs along axis 0 so consecutive quaternions lie in the same hemisphere (for slerp)."""
    q = np.array(q, dtype=np.float64, copy=True)
    for i in range(1, len(q)):
        if np.dot(q[i], q[i - 1]) < 0.0:
            q[i] = -q[i]
    return q


def slerp(q0: np.ndarray, q1: np.ndarray, t: np.ndarray) -> np.ndarray:
    """Spherical interpolation of wxyz quaternions [..., 4] at fractions t [...] (shortest path)."""
    t = np.asarray(t, dtype=np.float64)[..., None]
    d = np.sum(q0 * q1, axis=-1, keepdims=True)
    q1 = np.where(d < 0, -q1, q1)
    d = np.abs(d)
    theta = np.arccos(np.clip(d, -1.0, 1.0))
    s = np.sin(theta)
    small = s < 1e-6
    w0 = np.where(small, 1.0 - t, np.sin((1.0 - t) * theta) / np.where(small, 1.0, s))
    w1 = np.where(small, t, np.sin(t * theta) / np.where(small, 1.0, s))
    return quat_normalize(w0 * q0 + w1 * q1)


def _rx(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((o, z, z), -1), np.stack((z, c, -s), -1), np.stack((z, s, c), -1)), -2)


def _ry(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((c, z, s), -1), np.stack((z, o, z), -1), np.stack((-s, z, c), -1)), -2)


def _rz(a: np.ndarray) -> np.ndarray:
    a = np.asarray(a, dtype=np.float64)
    c, s, o, z = np.cos(a), np.sin(a), np.ones_like(a), np.zeros_like(a)
    return np.stack((np.stack((c, -s, z), -1), np.stack((s, c, z), -1), np.stack((z, z, o), -1)), -2)
