"""A task's plan, resolved against its compiled scene into per-subtask targets (TokenHSI terms).

`sample_target_from[i]` says where subtask i's target comes from:

- `traj_K`: trajectory K of the YAML (walked at the mean generator speed); target = its last
  waypoint (XY). `traj_rand`: a procedural trajectory per episode, starting at the pelvis.
- `tarpos_K`: the fixed world position `target_positions[K]`. For `carry` this is the box's
  destination and `target_object[i]` is the box to pick up.
- `scene_K`: object K. For `climb`/`sit` the target is its `tarClimbPos`/`tarSitPos`
  carried into the world by the object's current pose (objects may move). For `carry` it
  would name the box itself, which gives no destination: that is an error (use tarpos_K).

Subtask i of every env is tracked by the env; this module only holds the static description.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import torch

from detach.config_schema import SKILLS, TaskCfg

RAND = -1


@dataclass(frozen=True)
class Subtask:
    index: int
    skill: str
    source: str
    """'traj', 'tarpos' or 'scene'."""
    traj_id: int | None = None
    """Trajectory id for traj subtasks (RAND = procedural)."""
    obj: int = -1
    """Object of the subtask: the box for carry, the object for climb/sit (scene_K), else -1."""
    fixed_target: tuple[float, float, float] | None = None
    """World target when it does not move: tarpos_K, or the last waypoint (z = 0) of traj_K."""

    @property
    def skill_id(self) -> int:
        return SKILLS.index(self.skill)


def _parse(src: str) -> tuple[str, int]:
    kind, _, k = src.partition("_")
    if kind not in ("traj", "tarpos", "scene") or not k:
        raise ValueError(f"sample_target_from: expected traj_K, traj_rand, tarpos_K or scene_K, got '{src}'")
    if k == "rand":
        if kind != "traj":
            raise ValueError(f"sample_target_from: only traj_ may be random, got '{src}'")
        return kind, RAND
    return kind, int(k)


def compile_plan(task: TaskCfg) -> tuple[Subtask, ...]:
    """Validate and resolve the plan; errors are one line naming the task and the entry."""
    n = len(task.plan)
    where = f"task '{task.name}'"
    if n == 0:
        raise ValueError(f"{where}: plan is empty")
    if len(task.sample_target_from) != n or len(task.target_object) != n:
        raise ValueError(f"{where}: plan, target_object and sample_target_from must have the same length "
                         f"({n}, {len(task.target_object)}, {len(task.sample_target_from)})")
    out = []
    for i, (skill, src, obj) in enumerate(zip(task.plan, task.sample_target_from, task.target_object)):
        if skill not in SKILLS:
            raise ValueError(f"{where}: plan[{i}] '{skill}' is not one of {SKILLS}")
        try:
            kind, k = _parse(src)
        except ValueError as e:
            raise ValueError(f"{where}: sample_target_from[{i}]: {e}") from None
        ctx = f"{where}: subtask {i} ({skill} from {src})"
        if skill == "traj":
            if kind != "traj":
                raise ValueError(f"{ctx}: a traj subtask needs traj_K or traj_rand")
            if k == RAND:
                out.append(Subtask(i, skill, kind, traj_id=RAND))
                continue
            if k not in task.trajectories:
                raise ValueError(f"{ctx}: no trajectory {k} (have {sorted(task.trajectories)})")
            last = task.trajectories[k][-1]
            out.append(Subtask(i, skill, kind, traj_id=k, fixed_target=(float(last[0]), float(last[1]), 0.0)))
            continue
        if kind == "traj":
            raise ValueError(f"{ctx}: only traj subtasks take a trajectory")
        if kind == "tarpos":
            if not 0 <= k < len(task.target_positions):
                raise ValueError(f"{ctx}: no target_positions[{k}] (have {len(task.target_positions)})")
            tgt = tuple(float(v) for v in task.target_positions[k])
            box = obj if skill == "carry" else -1
            if skill == "carry":
                if not 0 <= obj < len(task.scene) or task.scene[obj].static:
                    raise ValueError(f"{ctx}: target_object[{i}] = {obj} must be a dynamic (static: false) object")
            out.append(Subtask(i, skill, kind, obj=box, fixed_target=tgt))  # type: ignore[arg-type]
            continue
        if not 0 <= k < len(task.scene):
            raise ValueError(f"{ctx}: no scene object {k} (have {len(task.scene)})")
        if skill == "carry":
            raise ValueError(f"{ctx}: scene_K names the box itself, which gives no destination; use tarpos_K")
        out.append(Subtask(i, skill, kind, obj=k))
    return tuple(out)


@dataclass
class PlanTensors:
    """The plan as tensors [S, ...] for batched lookups by each env's current subtask."""

    skill: torch.Tensor
    obj: torch.Tensor
    has_fixed: torch.Tensor
    fixed_target: torch.Tensor
    traj_id: torch.Tensor
    """-2 for non-traj subtasks, RAND (-1) for procedural, else the trajectory id."""

    @classmethod
    def build(cls, plan: tuple[Subtask, ...], device: torch.device | str) -> "PlanTensors":
        fixed = np.array([s.fixed_target if s.fixed_target is not None else (0.0, 0.0, 0.0) for s in plan])
        return cls(
            skill=torch.tensor([s.skill_id for s in plan], device=device),
            obj=torch.tensor([s.obj for s in plan], device=device),
            has_fixed=torch.tensor([s.fixed_target is not None for s in plan], device=device),
            fixed_target=torch.as_tensor(fixed, dtype=torch.float32, device=device),
            traj_id=torch.tensor([(s.traj_id if s.skill == "traj" else -2) for s in plan], device=device),
        )
