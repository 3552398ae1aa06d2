"""One read of the batched simulator state, sliced into what task logic needs.

`SceneIndex` turns a `SceneInfo` into index tensors once; `read_state` gathers the
character's bodies and hinges and the scene objects from the backend's batched views. All
world frame, float32, on the env's device.
"""

from __future__ import annotations

import math
from dataclasses import dataclass

import torch

from detach.envs import humanoid as H
from detach.envs.backend import PhysicsBackend
from scene_builder.scene import SceneInfo


@dataclass
class SceneIndex:
    body: torch.Tensor
    """[15] character body ids."""
    key: torch.Tensor
    """[4] positions of the key bodies (hands, feet) within `body`."""
    hands: torch.Tensor
    """[2] positions of the hands within `body`."""
    dof_q: torch.Tensor
    dof_v: torch.Tensor
    obj_body: torch.Tensor
    """[n_obj] object body ids."""
    obj_half: torch.Tensor
    """[n_obj, 3] half bbox sizes."""
    tar_sit: torch.Tensor
    tar_climb: torch.Tensor
    """[n_obj, 3] object-frame targets."""
    dyn: torch.Tensor
    """[K] object indices of the dynamic objects."""
    dyn_qpos: list[int]
    dyn_eq: list[int]
    dyn_rest_pos: torch.Tensor
    dyn_rest_quat: torch.Tensor
    body_rootid: torch.Tensor

    @classmethod
    def build(cls, scene: SceneInfo, model, device: torch.device) -> "SceneIndex":
        f = dict(dtype=torch.float32, device=device)
        objs = scene.objects
        dyn = [o for o in objs if not o.static]
        zero3 = torch.zeros(0, 3, **f)
        return cls(
            body=torch.as_tensor(scene.body_ids, device=device),
            key=torch.tensor([H.BODY_NAMES.index(b) for b in H.KEY_BODIES], device=device),
            hands=torch.tensor([H.BODY_NAMES.index("right_hand"), H.BODY_NAMES.index("left_hand")], device=device),
            dof_q=torch.as_tensor(scene.dof_qpos_adr, device=device),
            dof_v=torch.as_tensor(scene.dof_qvel_adr, device=device),
            obj_body=torch.tensor([o.body_id for o in objs], device=device, dtype=torch.long),
            obj_half=torch.tensor([list(o.bbox / 2) for o in objs], **f) if objs else zero3,
            tar_sit=torch.tensor([list(o.tar_sit_local) for o in objs], **f) if objs else zero3,
            tar_climb=torch.tensor([list(o.tar_climb_local) for o in objs], **f) if objs else zero3,
            dyn=torch.tensor([o.index for o in dyn], device=device, dtype=torch.long),
            dyn_qpos=[o.qpos_adr for o in dyn],
            dyn_eq=[o.grasp_eq for o in dyn],
            dyn_rest_pos=torch.tensor([list(o.pos) for o in dyn], **f) if dyn else zero3,
            dyn_rest_quat=torch.tensor([[math.cos(o.z_rot / 2), 0.0, 0.0, math.sin(o.z_rot / 2)] for o in dyn], **f)
            if dyn else torch.zeros(0, 4, **f),
            body_rootid=torch.as_tensor(model.body_rootid, device=device, dtype=torch.long),
        )


@dataclass
class SimState:
    body_pos: torch.Tensor
    body_quat: torch.Tensor
    body_lin: torch.Tensor
    body_ang: torch.Tensor
    """[N, 15, 3|4] character bodies, root (pelvis) first."""
    dof_pos: torch.Tensor
    dof_vel: torch.Tensor
    joint_power: torch.Tensor
    """[N] sum |tau * qdot| over the hinges, W."""
    obj_pos: torch.Tensor
    obj_quat: torch.Tensor
    obj_lin: torch.Tensor
    """[N, n_obj, 3|4] scene objects (bbox centres)."""

    @property
    def root_pos(self) -> torch.Tensor:
        return self.body_pos[:, 0]

    @property
    def root_quat(self) -> torch.Tensor:
        return self.body_quat[:, 0]


def read_state(be: PhysicsBackend, ix: SceneIndex) -> SimState:
    xpos, xquat, cvel, com = be.xpos, be.xquat, be.cvel, be.subtree_com
    bodies = torch.cat((ix.body, ix.obj_body))
    pos = xpos[:, bodies]
    ang = cvel[:, bodies, :3]
    lin = cvel[:, bodies, 3:] + torch.cross(ang, pos - com[:, ix.body_rootid[bodies]], dim=-1)
    quat = xquat[:, bodies]
    nb = ix.body.shape[0]
    qvel = be.qvel
    dof_vel = qvel[:, ix.dof_v]
    power = (be.qfrc_actuator[:, ix.dof_v] * dof_vel).abs().sum(-1)
    return SimState(
        body_pos=pos[:, :nb], body_quat=quat[:, :nb], body_lin=lin[:, :nb], body_ang=ang[:, :nb],
        dof_pos=be.qpos[:, ix.dof_q], dof_vel=dof_vel, joint_power=power,
        obj_pos=pos[:, nb:], obj_quat=quat[:, nb:], obj_lin=lin[:, nb:],
    )
