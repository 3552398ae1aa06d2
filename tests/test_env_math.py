"""Pure functions of the env: rotations, observation frames, height maps, trajectories."""

from __future__ import annotations

import math

import torch

from detach.config.schema import TrajectoryGenCfg
from detach.envs import observations as O
from detach.torch_math import (
    heading_matrix, quat_axes_xz, quat_from_yaw, quat_mul, quat_rotate, quat_to_matrix, quat_to_tan_norm,
    rotate_yaw_inverse, yaw_of,
)
from detach.skills.trajectories import distance_to_polyline, random_trajectories, sample_at, time_polyline


def _unit_quats(n: int, gen: torch.Generator) -> torch.Tensor:
    q = torch.randn(n, 4, generator=gen)
    return q / q.norm(dim=-1, keepdim=True)


def test_yaw_and_heading_frame():
    gen = torch.Generator().manual_seed(0)
    yaw = (torch.rand(8, generator=gen) * 2 - 1) * math.pi
    q = quat_from_yaw(yaw)
    assert torch.allclose(yaw_of(q), yaw, atol=1e-5)
    v = torch.randn(8, 3, generator=gen)
    assert torch.allclose(rotate_yaw_inverse(yaw, quat_rotate(q, v)), v, atol=1e-5)
    assert torch.allclose((quat_rotate(q, v)[:, None] @ heading_matrix(yaw))[:, 0], v, atol=1e-5)


def test_frames_are_invariant_to_world_yaw_and_position():
    """Rotating and shifting the whole world about +Z leaves self/env/amp frames unchanged."""
    gen = torch.Generator().manual_seed(1)
    n = 3
    pos = torch.randn(n, 15, 3, generator=gen)
    quat = _unit_quats(n * 15, gen).reshape(n, 15, 4)
    lin, ang = torch.randn(n, 15, 3, generator=gen), torch.randn(n, 15, 3, generator=gen)
    dof, dofv = torch.randn(n, 32, generator=gen), torch.randn(n, 32, generator=gen)
    target = torch.randn(n, 3, generator=gen)
    samples = torch.randn(n, 10, 2, generator=gen)
    opos, oquat, half = torch.randn(n, 3, generator=gen), _unit_quats(n, gen), torch.rand(n, 3, generator=gen)
    hm = torch.rand(n, 625, generator=gen)
    yes = torch.ones(n, dtype=torch.bool)

    def frames(pos, quat, lin, ang, target, samples, opos, oquat):
        R = heading_matrix(yaw_of(quat[:, 0]))
        s = O.self_frame(pos, quat, lin, ang, dof, dofv, R)
        e = O.env_frame(pos[:, 0], R, target, samples, yes, yes, opos, oquat, half, hm)
        a = O.amp_frame(pos[:, 0], quat[:, 0], lin[:, 0], ang[:, 0], dof, dofv, pos[:, [5, 8, 11, 14]])
        return s, e, a

    s0, e0, a0 = frames(pos, quat, lin, ang, target, samples, opos, oquat)
    assert s0.shape == (n, O.SELF_DIM) and e0.shape == (n, O.env_dim(25)) and a0.shape == (n, O.AMP_DIM)
    assert torch.allclose(s0[:, O.amp_index([5, 8, 11, 14])], a0, atol=1e-6)  # the env's gather
    yaw, shift = torch.tensor(0.7), torch.tensor([3.0, -2.0, 0.0])
    qz = quat_from_yaw(yaw)

    def rot(v):
        return quat_rotate(qz.expand(v.shape[:-1] + (4,)), v)

    def rq(q):
        return quat_mul(qz.expand(q.shape), q)

    s2d = torch.cat((samples, torch.zeros(n, 10, 1)), -1)
    s1, e1, a1 = frames(rot(pos) + shift, rq(quat), rot(lin), rot(ang), rot(target) + shift,
                        (rot(s2d) + shift)[..., :2], rot(opos) + shift, rq(oquat))
    for x, y in ((s0, s1), (e0, e1), (a0, a1)):
        assert torch.allclose(x, y, atol=1e-4)


def test_tan_norm_and_height_map_dynamic_box():
    gen = torch.Generator().manual_seed(2)
    q = _unit_quats(5, gen)
    assert torch.allclose(quat_to_tan_norm(q)[:, :3], quat_rotate(q, torch.tensor([1.0, 0, 0]).expand(5, 3)))
    raster = O.Raster(torch.zeros(40, 40), (-1.0, -1.0), 0.05)
    off = O.height_grid_offsets(25, 0.1, "cpu")
    root = torch.tensor([[0.0, 0.0, 0.9]])
    R = heading_matrix(torch.tensor([math.pi / 2]))  # facing +Y
    box = torch.tensor([[[0.0, 0.8, 0.25]]])  # 0.8 m ahead, 0.5 m tall
    hm = O.local_height_map(root, R, off, raster, box, torch.tensor([[[1.0, 0, 0, 0]]]),
                            torch.tensor([[0.2, 0.2, 0.25]])).reshape(25, 25)
    assert hm[12 + 8, 12] == torch.tensor(0.5) and hm[12, 12] == 0 and hm[12 - 8, 12] == 0
    assert hm[12 + 8, 12 + 3] == 0  # 0.3 m to the left of the box centre: off its 0.2 m half width


def test_random_trajectories_respect_the_generator_parameters():
    cfg = TrajectoryGenCfg()
    n = 64
    gen = torch.Generator().manual_seed(3)
    start = torch.randn(n, 2, generator=gen)
    verts, dt = random_trajectories(start, torch.zeros(n), cfg, duration=40.0, generator=gen)
    assert verts.shape == (n, cfg.num_verts, 2) and math.isclose(dt, 0.4)
    assert torch.equal(verts[:, 0], start)
    speed = (verts[:, 1:] - verts[:, :-1]).norm(dim=-1) / dt
    assert speed.min() >= cfg.speed_min - 1e-4 and speed.max() <= cfg.speed_max + 1e-4
    assert ((speed[:, 1:] - speed[:, :-1]).abs() / dt).max() <= cfg.accel_max + 1e-3


def test_timed_polyline_sampling_and_distance():
    pts = [[0.0, 0.0], [3.0, 0.0], [3.0, 4.0]]
    verts = torch.as_tensor(time_polyline(pts, speed=1.0, dt=0.1), dtype=torch.float32)[None]
    dt = torch.tensor([0.1])
    assert torch.allclose(verts[0, -1], torch.tensor([3.0, 4.0]))
    assert torch.allclose(sample_at(verts, dt, torch.tensor([2.0])), torch.tensor([[2.0, 0.0]]), atol=1e-5)
    assert torch.allclose(sample_at(verts, dt, torch.tensor([5.0])), torch.tensor([[3.0, 2.0]]), atol=1e-4)
    assert torch.allclose(sample_at(verts, dt, torch.tensor([60.0])), torch.tensor([[3.0, 4.0]]))
    d = distance_to_polyline(torch.tensor([[1.5, 0.5], [4.0, 2.0]]), verts.expand(2, -1, -1))
    assert torch.allclose(d, torch.tensor([0.5, 1.0]), atol=1e-5)


def test_rotation_matrices_from_quaternion_products_rotate_like_quat_rotate():
    """`quat_to_matrix` and `quat_axes_xz` are one outer product and one constant matrix
    product (~28 element-wise ops each before, benchmarks/RESULTS.md); the matrices must be
    the rotations `quat_rotate` applies, in float32 and float64."""
    gen = torch.Generator().manual_seed(3)
    for dtype, tol in ((torch.float32, 1e-6), (torch.float64, 1e-12)):
        q = _unit_quats(64, gen).to(dtype).reshape(4, 16, 4)
        q = q / q.norm(dim=-1, keepdim=True)  # unit in this dtype
        R = quat_to_matrix(q)
        v = torch.randn(4, 16, 3, generator=gen).to(dtype)
        torch.testing.assert_close((R @ v[..., None])[..., 0], quat_rotate(q, v), atol=tol, rtol=0)
        torch.testing.assert_close(R @ R.transpose(-1, -2), torch.eye(3, dtype=dtype).expand(4, 16, 3, 3),
                                   atol=tol, rtol=0)
        torch.testing.assert_close(quat_axes_xz(q), torch.cat((R[..., :, 0], R[..., :, 2]), -1), atol=tol, rtol=0)
