"""The humanoid: the shared body on a free root joint, actuated only through its 32 hinges.

The paper's character. Balance is its problem: it falls when its PD targets do not hold it
up. Action space: the 32 hinge PD targets (`detach.character.actions`).
"""

from __future__ import annotations

import mujoco
import torch

from detach.character.base import Character, register_character
from detach.character.body import NUM_DOF
from detach.torch_math import quat_from_yaw, quat_mul, quat_rotate_inverse, rotate_yaw


@register_character
class Humanoid(Character):
    name = "humanoid"
    root_joint = "root"
    num_actions = NUM_DOF
    action_std = 0.1
    """Measured (benchmarks/RESULTS.md): std 1 makes the PD targets jump by a joint's whole
    range, the power penalty then dominates and episodes end in ~37 steps."""

    def add_root(self, pelvis: mujoco.MjsBody) -> None:
        pelvis.add_freejoint(name=self.root_joint)

    def write_root(self, qpos, qvel, q_adr, v_adr, xy, height, yaw, tilt, lin, ang) -> None:
        qpos[:, q_adr:q_adr + 3] = torch.cat((xy, height[:, None]), dim=-1)
        qpos[:, q_adr + 3:q_adr + 7] = quat_mul(quat_from_yaw(yaw), tilt)
        qvel[:, v_adr:v_adr + 3] = rotate_yaw(yaw, lin)
        # free-joint angular velocity is in the body frame: heading-frame -> body frame
        qvel[:, v_adr + 3:v_adr + 6] = quat_rotate_inverse(tilt, ang)
