"""MotionState: a batch of reference-motion states queried from a MotionLib.

All tensors share leading batch dimensions [...] ([N] from `state()`, [N, T] from `windows()`)
and are in the world frame: positions in metres, velocities in m/s and rad/s, quaternions wxyz.
"""

from __future__ import annotations

from dataclasses import dataclass, fields

import torch

from detach.torch_math import quat_rotate_inverse


@dataclass
class MotionState:
    root_pos: torch.Tensor
    """[..., 3] pelvis origin, world, m."""
    root_quat: torch.Tensor
    """[..., 4] pelvis orientation, world, wxyz."""
    root_lin_vel: torch.Tensor
    """[..., 3] pelvis linear velocity, world, m/s."""
    root_ang_vel: torch.Tensor
    """[..., 3] pelvis angular velocity, WORLD frame, rad/s (MuJoCo's free-joint qvel[3:6]
    is in the body frame: use `to_mujoco()`)."""
    dof_pos: torch.Tensor
    """[..., 32] hinge angles, rad, DOF_NAMES order."""
    dof_vel: torch.Tensor
    """[..., 32] hinge velocities, rad/s."""
    body_pos: torch.Tensor
    """[..., 15, 3] body origins, world, m, BODY_NAMES order."""
    body_vel: torch.Tensor
    """[..., 15, 3] body origin velocities, world, m/s."""
    key_body_pos: torch.Tensor
    """[..., 4, 3] positions of KEY_BODIES (hands, feet), world, m."""

    def map(self, fn) -> "MotionState":
        """A new state with `fn` applied to every tensor (e.g. lambda x: x[mask])."""
        return MotionState(**{f.name: fn(getattr(self, f.name)) for f in fields(self)})

    def reshape_batch(self, *shape: int) -> "MotionState":
        """Reshape the leading batch dimensions, keeping each field's trailing dimensions."""
        out = {}
        for f in fields(self):
            x = getattr(self, f.name)
            trail = {"body_pos": 2, "body_vel": 2, "key_body_pos": 2}.get(f.name, 1)
            out[f.name] = x.reshape(*shape, *x.shape[x.dim() - trail:])
        return MotionState(**out)

    def to_mujoco(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(qpos [..., 39], qvel [..., 38]) of the free-root humanoid: [root pos, root quat, 32
        hinges] and [root lin vel (world), root ang vel (body frame), 32 hinge velocities]."""
        qpos = torch.cat((self.root_pos, self.root_quat, self.dof_pos), dim=-1)
        ang_local = quat_rotate_inverse(self.root_quat, self.root_ang_vel)
        qvel = torch.cat((self.root_lin_vel, ang_local, self.dof_vel), dim=-1)
        return qpos, qvel
