"""What skills read (`SkillServices`, `SkillContext`) and what their oracle pieces write.

`SkillServices` is fixed for an environment: its config, scene, height raster, the shared
trajectory reference, the random generator. The environment builds one `SkillContext` per
control step after physics: the state read from the simulator and each env's current subtask
(its skill, object, fixed target). Every tensor is [N, ...], world frame, metres, on the
env's device.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Any

import torch

from detach.sim.state import SimState

if TYPE_CHECKING:  # pragma: no cover - types only
    from detach.config.schema import RunConfig
    from detach.sim.raster import Raster
    from detach.skills.trajectories import TrajectoryReference
    from scene_builder.scene import SceneInfo


@dataclass(frozen=True)
class SkillServices:
    cfg: "RunConfig"
    scene: "SceneInfo"
    raster: "Raster"
    trajectory: "TrajectoryReference"
    generator: torch.Generator
    """The env's generator, on the env's device: every random draw of task logic comes from it
    (`torch.rand(..., generator=g, device=g.device)`)."""
    device: torch.device
    dt: float
    """Control step, seconds."""
    max_episode_length: int
    max_transition_steps: int
    num_envs: int
    """N: a skill's per-env state is made at `bind` (made later, a compiled step would compile twice)."""


@dataclass
class SkillContext:
    services: SkillServices
    state: SimState
    skill: torch.Tensor
    """[N] registry index of each env's current skill."""
    subtask: torch.Tensor
    """[N] index of each env's current subtask in the plan."""
    obj: torch.Tensor
    """[N] the subtask's object (scene index), -1 when it has none."""
    obj_pos: torch.Tensor
    obj_quat: torch.Tensor
    obj_lin: torch.Tensor
    obj_half: torch.Tensor
    """[N, 3|4] pose, linear velocity and half bbox size of the subtask's object (object 0's
    where it has none; see `has_obj`)."""
    obj_rest_z: torch.Tensor
    """[N] resting height (bbox centre z at reset) of the subtask's object, 0 without one."""
    fixed_target: torch.Tensor
    """[N, 3] the plan's fixed target of the subtask (zeros where it has none)."""
    has_fixed: torch.Tensor
    """[N] bool: the subtask has a fixed target."""
    held: torch.Tensor
    """[N] slot of the dynamic object the character holds by a constraint, -1 for none."""
    steps: torch.Tensor
    """[N] control steps since the episode started."""
    joint_power: torch.Tensor
    """[N] sum |tau * qdot| over the hinges (W), scaled by the character's weight."""
    dyn_speed: torch.Tensor
    """[N, K] speeds of the dynamic objects, m/s."""
    ref_xy: torch.Tensor
    """[N, 2] the trajectory reference point now."""
    ref_vel: torch.Tensor
    """[N, 2] the reference's velocity now (m/s; 0 once the path has ended)."""
    target: torch.Tensor = field(default=None)  # type: ignore[assignment]
    """[N, 3] world target of each env's subtask (filled by the env from the skills)."""
    goal: torch.Tensor = field(default=None)  # type: ignore[assignment]
    """[N, 3] the world point each env's character makes for now: the observation's target and,
    off a trajectory, its path points (`Skill.goal`; filled by the env from the skills)."""
    dist: torch.Tensor = field(default=None)  # type: ignore[assignment]
    """[N] anchor-to-target distance (filled by the env from the skills)."""
    extra: dict[str, Any] = field(default_factory=dict)
    """Per-step values a skill computes once and shares between its own hooks."""

    @property
    def cfg(self) -> "RunConfig":
        return self.services.cfg

    @property
    def has_obj(self) -> torch.Tensor:
        return self.obj >= 0

    @property
    def num_envs(self) -> int:
        return self.skill.shape[0]


@dataclass
class OracleCommand:
    """The scripted controller's wish per env, written by each skill's oracle piece where its
    subtasks are current: root velocity (world XY, m/s), target heading (rad), pelvis height
    (m), hinge targets [N, 32] (rad) and grasp (> 0 holds)."""

    velocity: torch.Tensor
    yaw_target: torch.Tensor
    height: torch.Tensor
    hinges: torch.Tensor
    grasp: torch.Tensor
    yaw: torch.Tensor
    """[N] current heading of the pelvis, rad (read only)."""
    ground: torch.Tensor
    """[N] height of the highest static surface under the pelvis (read only)."""
