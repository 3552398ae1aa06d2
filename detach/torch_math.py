"""Batched rotation math on torch tensors. Quaternions are wxyz, as MuJoCo stores them.

Heading frame: the world frame rotated about +Z by the root's yaw (the character faces +X),
so that observations do not depend on where the character looks in the world.
"""

from __future__ import annotations

import math

import torch


_INDICES: dict[tuple[tuple[int, ...], torch.device], torch.Tensor] = {}


def index_on(ids: tuple[int, ...], device: torch.device) -> torch.Tensor:
    """ids as a long tensor on device, made once per device: a Python list as an index is
    copied to the device on every use, and on an accelerator that copy waits for its queue.
    A plain dict, not `functools.cache`, which `torch.compile` would trace through; inside a
    compiled graph no cache at all: the tensor is the graph's constant, and a cache filled
    while tracing would fail the graph's guard on the next call (a second compile)."""
    if torch.compiler.is_compiling():
        return torch.tensor(ids, dtype=torch.long, device=device)
    out = _INDICES.get((ids, device))
    if out is None:
        out = _INDICES[(ids, device)] = torch.tensor(ids, dtype=torch.long, device=device)
    return out


def quat_mul(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    """Hamilton product a * b of wxyz quaternions [..., 4]."""
    aw, ax, ay, az = a.unbind(-1)
    bw, bx, by, bz = b.unbind(-1)
    return torch.stack((
        aw * bw - ax * bx - ay * by - az * bz,
        aw * bx + ax * bw + ay * bz - az * by,
        aw * by - ax * bz + ay * bw + az * bx,
        aw * bz + ax * by - ay * bx + az * bw,
    ), dim=-1)


def quat_conj(q: torch.Tensor) -> torch.Tensor:
    return torch.cat((q[..., :1], -q[..., 1:]), dim=-1)


def quat_rotate(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate vectors v [..., 3] by unit quaternions q [..., 4] (wxyz)."""
    w, xyz = q[..., :1], q[..., 1:]
    t = 2.0 * torch.cross(xyz, v, dim=-1)
    return v + w * t + torch.cross(xyz, t, dim=-1)


def quat_rotate_inverse(q: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Rotate vectors v by the inverse of q (world -> local frame of q)."""
    return quat_rotate(quat_conj(q), v)


def yaw_of(q: torch.Tensor) -> torch.Tensor:
    """Heading angle (rad) of the body's +X axis projected on the ground, wxyz input."""
    w, x, y, z = q.unbind(-1)
    return torch.atan2(2.0 * (w * z + x * y), 1.0 - 2.0 * (y * y + z * z))


def quat_from_yaw(yaw: torch.Tensor) -> torch.Tensor:
    """Rotation about +Z by yaw radians, wxyz [..., 4]."""
    h = 0.5 * yaw
    zero = torch.zeros_like(h)
    return torch.stack((torch.cos(h), zero, zero, torch.sin(h)), dim=-1)


def rotate_yaw_inverse(yaw: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """World vectors v [..., 3] (or [..., 2]) expressed in the heading frame of yaw [...].

    yaw must broadcast against v's leading dimensions.
    """
    c, s = torch.cos(yaw), torch.sin(yaw)
    x, y = v[..., 0], v[..., 1]
    xy = torch.stack((c * x + s * y, -s * x + c * y), dim=-1)
    return torch.cat((xy, v[..., 2:]), dim=-1)


def rotate_yaw(yaw: torch.Tensor, v: torch.Tensor) -> torch.Tensor:
    """Heading-frame vectors v [..., 2|3] back to the world frame."""
    return rotate_yaw_inverse(-yaw, v)


def quat_to_tan_norm(q: torch.Tensor) -> torch.Tensor:
    """6-D continuous rotation encoding: the rotated +X (tangent) and +Z (normal) axes."""
    ex = torch.zeros(q.shape[:-1] + (3,), dtype=q.dtype, device=q.device)
    ez = torch.zeros_like(ex)
    ex[..., 0] = 1.0
    ez[..., 2] = 1.0
    return torch.cat((quat_rotate(q, ex), quat_rotate(q, ez)), dim=-1)


def wrap_angle(a: torch.Tensor) -> torch.Tensor:
    """Angle(s) wrapped to [-pi, pi)."""
    return torch.remainder(a + math.pi, 2.0 * math.pi) - math.pi


def box_corners(pos: torch.Tensor, quat: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """World corners [..., 8, 3] of oriented boxes (centre [..., 3], wxyz [..., 4], half [..., 3])."""
    signs = torch.tensor([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)],
                         dtype=pos.dtype, device=pos.device)
    local = signs * half[..., None, :]
    return pos[..., None, :] + quat_rotate(quat[..., None, :].expand(local.shape[:-1] + (4,)), local)


def heading_matrix(yaw: torch.Tensor) -> torch.Tensor:
    """[N, 3, 3] rotation about +Z by yaw: world = R @ heading. World row vectors v [N, M, 3]
    are expressed in the heading frame by one batched product, `v @ R`."""
    c, s = torch.cos(yaw), torch.sin(yaw)
    z, o = torch.zeros_like(c), torch.ones_like(c)
    return torch.stack((c, -s, z, s, c, z, z, z, o), dim=-1).reshape(*yaw.shape, 3, 3)


def _rotation_table() -> torch.Tensor:
    """[16, 9]: the entries of R (row-major) as linear combinations of the products q_i q_j of a
    unit wxyz quaternion (index 4 i + j), e.g. R00 = ww + xx - yy - zz."""
    w, x, y, z = range(4)
    rows = (((w, w, 1), (x, x, 1), (y, y, -1), (z, z, -1)),  # R00
            ((x, y, 2), (w, z, -2)), ((x, z, 2), (w, y, 2)),  # R01, R02
            ((x, y, 2), (w, z, 2)),  # R10
            ((w, w, 1), (x, x, -1), (y, y, 1), (z, z, -1)),  # R11
            ((y, z, 2), (w, x, -2)), ((x, z, 2), (w, y, -2)), ((y, z, 2), (w, x, 2)),  # R12, R20, R21
            ((w, w, 1), (x, x, -1), (y, y, -1), (z, z, 1)))  # R22
    table = torch.zeros(16, 9)
    for col, terms in enumerate(rows):
        for i, j, c in terms:
            table[4 * i + j, col] += c / 2 if i != j else c  # q_i q_j and q_j q_i share the weight
            if i != j:
                table[4 * j + i, col] += c / 2
    return table


_ROTATION = _rotation_table()
_AXES_XZ = _ROTATION[:, [0, 3, 6, 2, 5, 8]]  # columns 0 and 2 of R: the rotated +X and +Z
_CONSTANTS: dict[tuple[int, torch.device, torch.dtype], torch.Tensor] = {}


def _constant(table: torch.Tensor, like: torch.Tensor) -> torch.Tensor:
    """`table` on `like`'s device and dtype, copied once per device and dtype (in a compiled
    graph: the graph's constant; see `index_on`)."""
    if torch.compiler.is_compiling():
        return table.to(like.device, like.dtype)
    key = (id(table), like.device, like.dtype)
    out = _CONSTANTS.get(key)
    if out is None:
        out = _CONSTANTS[key] = table.to(like.device, like.dtype)
    return out


def _from_products(q: torch.Tensor, table: torch.Tensor) -> torch.Tensor:
    """Linear functions of the products q_i q_j [..., 16] of quaternions q [..., 4]: one outer
    product and one matrix product with a constant instead of ~28 small element-wise ops
    (the env step calls these for 15 bodies and every object; benchmarks/RESULTS.md)."""
    products = (q[..., :, None] * q[..., None, :]).flatten(-2)
    return products @ _constant(table, q)


def quat_axes_xz(q: torch.Tensor) -> torch.Tensor:
    """The rotated +X and +Z axes [..., 6] of unit wxyz quaternions (= `quat_to_tan_norm`)."""
    return _from_products(q, _AXES_XZ)


def quat_to_matrix(q: torch.Tensor) -> torch.Tensor:
    """[..., 3, 3] rotation matrices of unit wxyz quaternions (columns = rotated axes)."""
    return _from_products(q, _ROTATION).reshape(*q.shape[:-1], 3, 3)


_CORNER_SIGNS = torch.tensor([[sx, sy, sz] for sx in (-1.0, 1.0) for sy in (-1.0, 1.0) for sz in (-1.0, 1.0)])


def box_corners_fast(pos: torch.Tensor, quat: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """As `box_corners` for [N, 3] boxes ([N, 8, 3]), with one batched matrix product."""
    local = _constant(_CORNER_SIGNS, pos) * half[:, None, :]
    return pos[:, None, :] + local @ quat_to_matrix(quat).transpose(-1, -2)


def point_box_distance(p: torch.Tensor, box_pos: torch.Tensor, box_quat: torch.Tensor,
                       half: torch.Tensor) -> torch.Tensor:
    """Distance (m) from points p [..., 3] to oriented boxes (centre, wxyz quat, half sizes).

    0 inside the box. Broadcasts over leading dimensions.
    """
    local = quat_rotate_inverse(box_quat, p - box_pos)
    excess = (local.abs() - half).clamp(min=0.0)
    return excess.norm(dim=-1)
