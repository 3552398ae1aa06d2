"""One read of the batched simulator state, sliced into what task logic needs.

`SceneIndex` turns a `SceneInfo` into index tensors once; `read_state` gathers the
character's bodies and hinges and the scene objects from the backend's batched views. All
world frame, float32, on the env's device.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch

from detach.character.body import BODY_NAMES, HANDS, KEY_BODIES
from detach.sim.backend import PhysicsBackend
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
    dyn: torch.Tensor
    """[K] object indices of the dynamic objects."""

    @classmethod
    def build(cls, scene: SceneInfo, device: torch.device) -> "SceneIndex":
        f = dict(dtype=torch.float32, device=device)
        objs = scene.objects
        dyn = [o for o in objs if not o.static]
        zero3 = torch.zeros(0, 3, **f)
        return cls(
            body=torch.as_tensor(scene.body_ids, device=device),
            key=torch.tensor([BODY_NAMES.index(b) for b in KEY_BODIES], device=device),
            hands=torch.tensor([BODY_NAMES.index(b) for b in HANDS], device=device),
            dof_q=torch.as_tensor(scene.dof_qpos_adr, device=device),
            dof_v=torch.as_tensor(scene.dof_qvel_adr, device=device),
            obj_body=torch.tensor([o.body_id for o in objs], device=device, dtype=torch.long),
            obj_half=torch.tensor([list(o.bbox / 2) for o in objs], **f) if objs else zero3,
            dyn=torch.tensor([o.index for o in dyn], device=device, dtype=torch.long),
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


def read_state(backend: PhysicsBackend, index: SceneIndex) -> SimState:
    bodies = torch.cat((index.body, index.obj_body))
    lin, ang = backend.body_velocities()
    pos, quat, lin, ang = backend.xpos[:, bodies], backend.xquat[:, bodies], lin[:, bodies], ang[:, bodies]
    nb = index.body.shape[0]
    dof_vel = backend.qvel[:, index.dof_v]
    power = (backend.qfrc_actuator[:, index.dof_v] * dof_vel).abs().sum(-1)
    return SimState(
        body_pos=pos[:, :nb], body_quat=quat[:, :nb], body_lin=lin[:, :nb], body_ang=ang[:, :nb],
        dof_pos=backend.qpos[:, index.dof_q], dof_vel=dof_vel, joint_power=power,
        obj_pos=pos[:, nb:], obj_quat=quat[:, nb:], obj_lin=lin[:, nb:],
    )
