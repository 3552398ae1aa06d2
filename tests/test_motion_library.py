"""MotionLib: packing, skill-weighted sampling, interpolation, finite-difference velocities, windows."""

from __future__ import annotations

import math

import numpy as np
import pytest
import torch

from detach.character.body import BODY_NAMES, DOF_NAMES, KEY_BODIES
from detach.skills import skill_class
from detach.motion.clip import clip_from_arrays, save_clip
from detach.motion.library import MotionLib
from detach.motion.rotations import quat_from_yaw_pitch


def line_clip(name: str, skill: str = "walk", frames: int = 31, fps: float = 30.0,
              vel=(1.2, -0.3, 0.1), yaw_rate: float = 0.0, dof_rate: float = 0.5):
    """Root moving at constant velocity (m/s), turning at yaw_rate (rad/s), every hinge at dof_rate."""
    t = np.arange(frames) / fps
    root = np.array([0.5, 1.0, 0.9]) + t[:, None] * np.array(vel)
    quat = quat_from_yaw_pitch(yaw_rate * t, np.zeros(frames))
    dof = 0.01 * np.arange(len(DOF_NAMES))[None] + dof_rate * t[:, None]
    body = root[:, None, :] + 0.1 * np.arange(len(BODY_NAMES))[None, :, None] + 0.2 * t[:, None, None]
    return clip_from_arrays(name, skill, fps, root, quat, dof, body)


def test_sampling_respects_skill_weights():
    clips = [line_clip("w1"), line_clip("w2", frames=91), line_clip("s1", "sit"),
             line_clip("i1", "idle"), line_clip("i2", "idle"), line_clip("i3", "idle")]
    lib = MotionLib(clips, skill_weights={"walk": 0.5, "sit": 0.3, "idle": 0.2})
    g = torch.Generator().manual_seed(0)
    n = 200_000
    counts = torch.bincount(lib.sample_clips(n, generator=g), minlength=6).double() / n
    expect = torch.tensor([0.25, 0.25, 0.3, 0.2 / 3, 0.2 / 3, 0.2 / 3], dtype=torch.float64)
    assert torch.allclose(counts, expect, atol=0.006), counts
    # restricted to a skill's labels (sit's motion_labels = sit, walk): renormalised over both
    labels = skill_class("sit").motion_labels
    probs = lib.clip_probs(labels)
    expect = torch.tensor([0.3125, 0.3125, 0.375, 0, 0, 0], dtype=torch.float64)
    assert torch.allclose(probs, expect)
    sub = torch.bincount(lib.sample_clips(n, skills=labels, generator=g), minlength=6).double() / n
    assert torch.allclose(sub, expect, atol=0.006)
    assert torch.allclose(lib.clip_probs(["idle"]), torch.tensor([0, 0, 0, 1 / 3, 1 / 3, 1 / 3], dtype=torch.float64))
    # within a label by duration: w2 is 3 s long, w1 1 s
    lib_len = MotionLib(clips[:2], weight_by_length=True)
    assert torch.allclose(lib_len.clip_probs(), torch.tensor([0.25, 0.75], dtype=torch.float64))
    # uniform over labels present by default
    lib_u = MotionLib(clips)
    assert lib_u.clip_probs().tolist() == pytest.approx([1 / 6, 1 / 6, 1 / 3, 1 / 9, 1 / 9, 1 / 9])
    with pytest.raises(ValueError, match="unknown skill"):
        MotionLib(clips, skill_weights={"swim": 1.0})
    with pytest.raises(ValueError, match="no clips"):
        lib.sample_clips(3, skills=["carry"])


def test_sample_times_within_truncated_length():
    lib = MotionLib([line_clip("a", frames=31), line_clip("b", frames=4)])
    ids = torch.tensor([0] * 500 + [1] * 500)
    t = lib.sample_times(ids, truncate_s=0.3)
    assert (t[:500] >= 0).all() and (t[:500] <= 0.7 + 1e-6).all() and t[:500].max() > 0.6
    assert (t[500:] == 0).all()  # clip b (0.1 s) is shorter than the truncation


def test_state_exact_at_frames_and_linear_between():
    clip = line_clip("a", yaw_rate=1.0)
    rng = np.random.default_rng(1)
    clip.dof_pos = clip.dof_pos + rng.normal(size=clip.dof_pos.shape)  # not linear in time
    lib = MotionLib([line_clip("z", frames=7), clip], dtype=torch.float64)
    k = torch.arange(clip.num_frames)
    s = lib.state(torch.ones_like(k), k.double() / 30.0)  # float64 times: exact frame instants
    np.testing.assert_allclose(s.dof_pos.numpy(), clip.dof_pos, atol=1e-9)
    np.testing.assert_allclose(s.root_pos.numpy(), clip.root_pos, atol=1e-9)
    np.testing.assert_allclose(s.root_quat.numpy(), clip.root_quat, atol=1e-9)
    np.testing.assert_allclose(s.body_pos.numpy(), clip.body_pos, atol=1e-9)
    keys = [BODY_NAMES.index(b) for b in KEY_BODIES]
    np.testing.assert_allclose(s.key_body_pos.numpy(), clip.body_pos[:, keys], atol=1e-9)
    # between frames 3 and 4 at 30 %: linear for angles/positions, slerp (= yaw 3.3 / 30 rad) for the root
    mid = lib.state(torch.tensor([1]), torch.tensor([3.3 / 30.0], dtype=torch.float64))
    np.testing.assert_allclose(mid.dof_pos[0].numpy(), 0.7 * clip.dof_pos[3] + 0.3 * clip.dof_pos[4], atol=1e-9)
    expect_q = quat_from_yaw_pitch(np.array([3.3 / 30.0]), np.zeros(1))[0]
    np.testing.assert_allclose(mid.root_quat[0].numpy(), expect_q, atol=1e-9)
    # out of range times clamp to the first / last frame
    ends = lib.state(torch.tensor([1, 1]), torch.tensor([-1.0, 99.0]))
    np.testing.assert_allclose(ends.dof_pos.numpy(), clip.dof_pos[[0, -1]], atol=1e-9)


def test_finite_difference_velocities_of_constant_motion():
    lib = MotionLib([line_clip("a", yaw_rate=0.8, dof_rate=0.5), line_clip("b", vel=(0, 2.0, 0))])
    ids = torch.tensor([0, 0, 0, 1])
    s = lib.state(ids, torch.tensor([0.0, 0.51, 1.0, 0.2]))
    np.testing.assert_allclose(s.root_lin_vel[:3].numpy(), [[1.2, -0.3, 0.1]] * 3, atol=1e-4)
    np.testing.assert_allclose(s.root_lin_vel[3].numpy(), [0, 2.0, 0], atol=1e-4)
    np.testing.assert_allclose(s.root_ang_vel[:3].numpy(), [[0, 0, 0.8]] * 3, atol=1e-4)  # world frame
    np.testing.assert_allclose(s.dof_vel.numpy(), 0.5, atol=1e-4)
    np.testing.assert_allclose(s.body_vel[:3].numpy(), np.broadcast_to(np.array([1.4, -0.1, 0.3]), (3, 15, 3)),
                               atol=1e-4)
    qpos, qvel = s.to_mujoco()
    assert qpos.shape == (4, 39) and qvel.shape == (4, 38)
    # free-joint angular velocity is in the body frame: yaw about world z is also about body z here
    np.testing.assert_allclose(qvel[:3, 3:6].numpy(), [[0, 0, 0.8]] * 3, atol=1e-4)


def test_windows_shapes_and_order(tmp_path):
    save_clip(line_clip("a", frames=61), tmp_path / "a.npz")
    lib = MotionLib([tmp_path, line_clip("b", "idle")])  # a folder and a clip object
    assert lib.clip_names == ["a", "b"]
    ids = torch.tensor([0, 0, 1])
    end = torch.tensor([1.5, 0.1, 0.5])
    w = lib.windows(ids, end, steps=10, dt=1 / 30)
    assert w.root_pos.shape == (3, 10, 3) and w.root_quat.shape == (3, 10, 4)
    assert w.dof_pos.shape == (3, 10, 32) and w.body_pos.shape == (3, 10, 15, 3)
    assert w.key_body_pos.shape == (3, 10, 4, 3) and w.root_ang_vel.shape == (3, 10, 3)
    # oldest first: x advances 1.2 m/s * 1/30 s per step, the last step is at end_time
    dx = torch.diff(w.root_pos[0, :, 0])
    assert torch.allclose(dx, torch.full_like(dx, 0.04), atol=1e-5)
    last = lib.state(ids, end)
    assert torch.allclose(w.root_pos[:, -1], last.root_pos, atol=1e-6)
    # a window reaching before t = 0 repeats the first frame
    first = lib.state(torch.tensor([0]), torch.tensor([0.0]))
    assert torch.allclose(w.root_pos[1, :7], first.root_pos.expand(7, 3), atol=1e-6)
    ids2, w2 = lib.sample_windows(64, steps=4, dt=0.1, skills=["walk"])
    assert (ids2 == 0).all() and w2.dof_pos.shape == (64, 4, 32)
    assert (torch.diff(w2.root_pos[..., 0], dim=1) > 0.11).all()  # whole window inside the clip


def test_duplicate_names_rejected():
    with pytest.raises(ValueError, match="duplicate clip name"):
        MotionLib([line_clip("a"), line_clip("a")])


def test_quaternion_sign_flips_do_not_break_velocity():
    clip = line_clip("a", yaw_rate=0.8)
    clip.root_quat[1::2] *= -1  # same rotations, alternating signs
    lib = MotionLib([clip])
    s = lib.state(torch.zeros(3, dtype=torch.long), torch.tensor([0.1, 0.45, 0.9]))
    np.testing.assert_allclose(s.root_ang_vel.numpy(), [[0, 0, 0.8]] * 3, atol=1e-4)
    assert math.isclose(float(s.root_quat.norm(dim=-1).min()), 1.0, abs_tol=1e-6)
