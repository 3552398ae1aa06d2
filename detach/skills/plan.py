"""A task's plan, resolved against the skill registry into `Subtask`s (TokenHSI terms).

`sample_target_from[i]` says where subtask i's target comes from: `traj_K` (trajectory K;
`traj_rand` a procedural one per episode), `tarpos_K` (the fixed world position
`target_positions[K]`) or `scene_K` (object K). `target_object[i]` names the subtask's object
where its skill needs one (the box for carry). The config loader checks that every source
exists; each skill checks the entries it is given (`Skill.compile_entry`).
"""

from __future__ import annotations

import dataclasses
from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import torch

from detach.config.schema import TaskCfg
from detach.skills.base import RAND, PlanError, Subtask
from detach.skills.registry import canonical_name, skill_class


def parse_source(src: str) -> tuple[str, int]:
    """'traj_3' -> ('traj', 3); 'traj_rand' -> ('traj', RAND)."""
    kind, _, k = src.partition("_")
    return kind, RAND if k == "rand" else int(k)


def compile_plan(task: TaskCfg) -> tuple[Subtask, ...]:
    """Every plan entry through its skill; raises `PlanError` (with the task key) when one
    cannot run."""
    if not task.plan:
        raise PlanError(("plan",), "expected at least one skill, found an empty plan")
    out = []
    for i, (name, src, obj) in enumerate(zip(task.plan, task.sample_target_from, task.target_object)):
        try:
            skill = skill_class(name)()
        except ValueError as exc:
            raise PlanError(("plan", i), str(exc)) from None
        kind, ref = parse_source(src)
        choices = obj if isinstance(obj, tuple) else (obj,)
        if not choices:
            raise PlanError(("target_object", i), "expected an object index or a non-empty list of them")
        entries = [skill.compile_entry(i, kind, ref, c, task) for c in choices]
        objects = tuple(dict.fromkeys(e.obj for e in entries))
        out.append(dataclasses.replace(entries[0], choices=objects) if len(objects) > 1 else entries[0])
    return tuple(out)


@dataclass
class PlanTensors:
    """The plan as tensors [S, ...] for batched lookups by each env's current subtask."""

    skill: torch.Tensor
    """Index of each subtask's skill in the run's skills (`run_skills`)."""
    obj: torch.Tensor
    has_fixed: torch.Tensor
    fixed_target: torch.Tensor

    @classmethod
    def build(cls, plan: tuple[Subtask, ...], skills: Sequence[str], device: torch.device | str) -> "PlanTensors":
        fixed = np.array([s.fixed_target if s.fixed_target is not None else (0.0, 0.0, 0.0) for s in plan])
        return cls(
            skill=torch.tensor([skills.index(s.skill) for s in plan], device=device),
            obj=torch.tensor([s.obj for s in plan], device=device),
            has_fixed=torch.tensor([s.fixed_target is not None for s in plan], device=device),
            fixed_target=torch.as_tensor(fixed, dtype=torch.float32, device=device),
        )


__all__ = ["PlanTensors", "compile_plan", "canonical_name", "parse_source"]
