"""Initial states of episodes: the character at `humanoid.init_pos2d`, objects at `pos3d`.

The character writes its own root (`Character.write_root`: a free joint, or the puppet's
slides); this module decides where it stands, which way it faces and in what pose.

Yaw: uniform in [-pi, pi) when `humanoid.init_rot_randomize`, else `humanoid.init_yaw`.
Pose (`env.init`): `default` = the standing default pose; `random` = a reference state from
`reference_sampler` (set by the motion library for reference-state initialisation; without
one, the default pose with N(0, 0.05 rad) hinge noise); `mixed` = `random` with probability
`env.mixed_init_prob`, else `default`.

Mid-task starts (`env.mid_task_init_prob`, training only): with that probability an episode whose
first subtask's skill offers them (`Skill.mid_task_start`, e.g. Carry's box carried part of the
way) starts there instead, the character holding the object where the start says so.

A reference sampler is `fn(n, generator) -> dict` with "root_height" [n] (m), "root_quat"
[n, 4] (wxyz; its yaw is replaced by the start yaw), "dof_pos" [n, 32], and optionally
"dof_vel" [n, 32], "root_lin_vel" and "root_ang_vel" [n, 3] in the heading frame.
"""

from __future__ import annotations

import math
from typing import Callable

import mujoco
import torch

from detach.character import Character
from detach.character.body import NUM_DOF, START_HEIGHT, dof_ranges
from detach.config.schema import RunConfig
from detach.host_sync import to_device_async
from detach.skills import MidTaskStart, Skill
from detach.torch_math import quat_conj, quat_from_yaw, quat_mul, yaw_of
from scene_builder.scene import SceneInfo

ReferenceSampler = Callable[[int, torch.Generator], dict]


class ResetSampler:
    def __init__(self, cfg: RunConfig, scene: SceneInfo, model: mujoco.MjModel, character: Character,
                 gen: torch.Generator, device: torch.device) -> None:
        self.cfg, self.scene, self.character, self.gen, self.device = cfg, scene, character, gen, device
        self.qpos0 = torch.as_tensor(model.qpos0, dtype=torch.float32, device=device)
        self.nv = model.nv
        self.reference_sampler: ReferenceSampler | None = None
        self.init_xy = torch.tensor(cfg.task.humanoid.init_pos2d, dtype=torch.float32, device=device)
        self.obj_rest = torch.tensor([list(o.pos) for o in scene.objects], dtype=torch.float32,
                                     device=device).reshape(-1, 3)
        """Resting bbox centre of each object (its position at reset), indexed by object."""
        self.rest_z = torch.cat((self.obj_rest[:, 2], torch.zeros(1, device=device)))
        """Resting height of each object, indexed by object; [-1] (no object) is 0."""
        # Constants of every reset, on the device once: made from host data inside a reset,
        # each would be a host-to-device copy, which waits for the device's queue.
        self.upright = torch.tensor([1.0, 0.0, 0.0, 0.0], device=device)
        self.dof_qpos_adr = torch.as_tensor(scene.dof_qpos_adr, dtype=torch.long, device=device)
        self.dof_qvel_adr = torch.as_tensor(scene.dof_qvel_adr, dtype=torch.long, device=device)
        self.dof_range = torch.as_tensor(dof_ranges(), dtype=torch.float32, device=device)
        self.free_rest = [(o.qpos_adr, torch.tensor([*o.pos, math.cos(o.z_rot / 2), 0.0, 0.0, math.sin(o.z_rot / 2)],
                                                    dtype=torch.float32, device=device))
                          for o in scene.objects if not o.static]
        """(qpos address, resting position and quaternion [7]) of each free object."""

    def _rand(self, *shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=self.gen, device=self.gen.device).to(self.device)

    def _use_reference(self, n: int) -> torch.Tensor:
        mode = self.cfg.env.init
        if mode == "default":
            return torch.zeros(n, dtype=torch.bool, device=self.device)
        if mode == "random":
            return torch.ones(n, dtype=torch.bool, device=self.device)
        return self._rand(n) < self.cfg.env.mixed_init_prob

    def sample(self, ids: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
        """(qpos [n, nq], qvel [n, nv], root XY [n, 2]) for the envs ids."""
        n = len(ids)
        hc = self.cfg.task.humanoid
        yaw = (self._rand(n) * 2 - 1) * math.pi if hc.init_rot_randomize else torch.full((n,), hc.init_yaw,
                                                                                           device=self.device)
        xy = self.init_xy.expand(n, 2).clone()
        height = torch.full((n,), START_HEIGHT, device=self.device)
        tilt = self.upright.expand(n, 4).clone()
        dof = torch.zeros(n, NUM_DOF, device=self.device)
        dof_vel = torch.zeros(n, NUM_DOF, device=self.device)
        lin = torch.zeros(n, 3, device=self.device)
        ang = torch.zeros(n, 3, device=self.device)
        ref = self._use_reference(n)
        if self.cfg.env.init != "default":  # drawn for all n starts, kept where ref: no host read of ref
            r1 = ref[:, None]
            if self.reference_sampler is not None:
                # the clips live on the host (detach.train.setup): copied without waiting
                r = {key: to_device_async(v, self.device) for key, v in self.reference_sampler(n, self.gen).items()}
                q = r["root_quat"]
                tilt = torch.where(r1, quat_mul(quat_conj(quat_from_yaw(yaw_of(q))), q), tilt)
                height = torch.where(ref, r["root_height"], height)
                dof = torch.where(r1, r["dof_pos"], dof)
                dof_vel, lin, ang = (torch.where(r1, r[key], dst) if key in r else dst
                                     for key, dst in (("dof_vel", dof_vel), ("root_lin_vel", lin),
                                                      ("root_ang_vel", ang)))
            else:
                noise = torch.randn(n, NUM_DOF, generator=self.gen, device=self.gen.device).to(self.device) * 0.05
                rng = self.dof_range
                dof = torch.where(r1, torch.maximum(torch.minimum(noise, rng[:, 1]), rng[:, 0]), dof)
        qpos = self.qpos0.expand(n, -1).clone()
        qvel = torch.zeros(n, self.nv, device=self.device)
        self.character.write_root(qpos, qvel, self.scene.root_qpos_adr, self.scene.root_qvel_adr,
                                  xy, height, yaw, tilt, lin, ang)
        qpos[:, self.dof_qpos_adr] = dof
        qvel[:, self.dof_qvel_adr] = dof_vel
        for adr, rest in self.free_rest:
            qpos[:, adr:adr + 7] = rest
        return qpos, qvel, xy

    def mid_task(self, ids: torch.Tensor, objects: torch.Tensor, skill: Skill, target: torch.Tensor,
                 obj_half: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor, root_xy: torch.Tensor
                 ) -> tuple[torch.Tensor, MidTaskStart] | None:
        """Turn a share `env.mid_task_init_prob` of the starts (qpos, qvel, root_xy of envs ids, as
        `sample` made them; changed in place) into `skill`'s mid-task starts, its first subtask
        on objects [n] with fixed target [3]; obj_half [K, 3] the half sizes of every scene
        object (`SceneIndex.obj_half`). Returns (picked [n] bool, the start of every row) or
        None when the skill has no mid-task start. Starts are made for all n rows and kept
        where picked: choosing the rows would need a host read."""
        n = len(ids)
        pick = self._rand(n) < self.cfg.env.mid_task_init_prob
        start = skill.mid_task_start(objects, self.obj_rest[objects], obj_half[objects], target.expand(n, 3), self.gen)
        if start is None:
            return None
        q, v = qpos.clone(), qvel.clone()
        zeros = torch.zeros(n, 3, device=self.device)
        self.character.write_root(q, v, self.scene.root_qpos_adr, self.scene.root_qvel_adr, start.root_xy,
                                  start.height, start.yaw, self.upright.expand(n, 4), zeros, zeros)
        q[:, self.dof_qpos_adr] = start.hinges
        v.index_fill_(1, self.dof_qvel_adr, 0.0)
        for i in self.scene.dynamic:
            o = self.scene.objects[i]
            sel = (objects == i)[:, None]
            pose = slice(o.qpos_adr, o.qpos_adr + 7)  # free joint: position, then quaternion
            q[:, pose] = torch.where(sel, torch.cat((start.obj_pos, start.obj_quat), -1), q[:, pose])
            v[:, o.qvel_adr:o.qvel_adr + 6] = torch.where(sel, 0.0, v[:, o.qvel_adr:o.qvel_adr + 6])
        rows = pick[:, None]
        qpos.copy_(torch.where(rows, q, qpos))
        qvel.copy_(torch.where(rows, v, qvel))
        root_xy.copy_(torch.where(rows, start.root_xy, root_xy))
        return pick, start
