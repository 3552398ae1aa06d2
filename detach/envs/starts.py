"""Where each new episode starts, as one `StartPlan` the env carries out.

Three kinds of start, drawn in this order from the env's generator for every env that resets
(kept by mask, no host read): the reset state (`ResetSampler.sample`: pose, place, facing);
with `env.mid_task_init_prob` the first skill's mid-task start (`Skill.mid_task_start`, e.g.
Carry's box held on its way); with `env.subtask_start_prob` a recorded state at the
beginning of a later subtask (`SubtaskStarts`, recorded by the train layer with the scripted
oracle and handed to the env). Both of the latter are training-only, and both may start the
character holding an object, which the plan says (`StartPlan.holds`).
"""

from __future__ import annotations

import math
from dataclasses import dataclass
from typing import Callable

import torch

from detach.config.schema import RunConfig
from detach.envs.resets import ResetSampler
from detach.envs.subtask_starts import SubtaskStarts
from detach.envs.world import World
from detach.skills import Skill, Subtask
from detach.torch_math import quat_from_yaw


@dataclass(frozen=True)
class Hold:
    """The objects some of the resetting envs start holding [n, ...] (world frame, wxyz)."""

    slot: torch.Tensor
    """[n] slot of the held object among the dynamic objects; -1 where none is held."""
    root_pos: torch.Tensor
    root_quat: torch.Tensor
    obj_pos: torch.Tensor
    obj_quat: torch.Tensor


@dataclass(frozen=True)
class StartPlan:
    """The starts of the n envs that reset, row i for env ids[i]."""

    qpos: torch.Tensor
    qvel: torch.Tensor
    root_xy: torch.Tensor
    """[n, 2]"""
    objects: torch.Tensor
    """[n, S] the object of every subtask of the new episodes."""
    started_later: torch.Tensor
    """[n] bool: the episode starts mid-task or at a later subtask (its success is not the plan's)."""
    holds: tuple[Hold, ...] = ()
    begins_later: torch.Tensor | None = None
    """[n] bool: the rows that begin at `begin_subtask` instead of the first subtask."""
    begin_subtask: torch.Tensor | None = None


class EpisodeStarts:
    """Plans the starts of resetting envs; see the module docstring."""

    def __init__(self, cfg: RunConfig, plan: tuple[Subtask, ...], world: World, resets: ResetSampler,
                 skills: dict[int, Skill], recorded: SubtaskStarts | None, eval_mode: bool) -> None:
        self.cfg, self.world, self.resets = cfg, world, resets
        self.recorded = None if eval_mode or cfg.env.subtask_start_prob <= 0 else _library(cfg, recorded)
        """The recorded later-subtask starts drawn from (training with `env.subtask_start_prob`)."""
        self.gen, self.device = resets.gen, resets.device
        self.mid_task_skill = None if eval_mode else _mid_task_skill(cfg, plan, world, skills)
        fixed = plan[0].fixed_target
        self.mid_task_target = None if self.mid_task_skill is None else torch.tensor(
            fixed if fixed is not None else [math.nan] * 3, dtype=torch.float32, device=self.device)

    def plan(self, ids: torch.Tensor, draw_objects: Callable[[torch.Tensor], torch.Tensor]) -> StartPlan:
        """The starts of envs ids; draw_objects(ids) -> [n, S] draws each episode's objects."""
        qpos, qvel, root_xy = self.resets.sample(ids)
        objects = draw_objects(ids)
        later = torch.zeros(len(ids), dtype=torch.bool, device=self.device)
        holds: list[Hold] = []
        if self.mid_task_skill is not None:
            mid = self.resets.mid_task(ids, objects[:, 0], self.mid_task_skill, self.mid_task_target,
                                       self.world.index.obj_half, qpos, qvel, root_xy)
            if mid is not None:
                later, start = mid
                slot = torch.where(later & start.held, self.world.dyn_slot[objects[:, 0]], -1)
                root = torch.cat((start.root_xy, start.height[:, None]), -1)
                holds.append(Hold(slot, root, quat_from_yaw(start.yaw), start.obj_pos, start.obj_quat))
        if self.recorded is None:
            return StartPlan(qpos, qvel, root_xy, objects, later, tuple(holds))
        draw = torch.rand(len(ids), generator=self.gen, device=self.gen.device).to(self.device)
        late = (draw < self.cfg.env.subtask_start_prob) & ~later
        st = self.recorded
        pick = st.draw(len(ids), self.gen)
        rows = late[:, None]
        qpos = torch.where(rows, st.qpos[pick], qpos)
        qvel = torch.where(rows, st.qvel[pick], qvel)
        root_xy = torch.where(rows, st.root_pos[pick, :2], root_xy)
        objects = torch.where(rows, st.objects[pick], objects)
        holds.append(Hold(torch.where(late, st.held[pick], -1), st.root_pos[pick], st.root_quat[pick],
                          st.held_pos[pick], st.held_quat[pick]))
        return StartPlan(qpos, qvel, root_xy, objects, later | late, tuple(holds), late, st.subtask[pick])


def _library(cfg: RunConfig, starts: SubtaskStarts | None) -> SubtaskStarts | None:
    """The recorded later-subtask starts a training env with `env.subtask_start_prob` draws
    from (None where the oracle began no later subtask); the train layer records them."""
    if starts is None:
        raise ValueError(f"env.subtask_start_prob: {cfg.env.subtask_start_prob} starts training episodes from "
                         "recorded states: make the env with detach.train.start_library.make_training_env")
    return starts if len(starts) else None


def _mid_task_skill(cfg: RunConfig, plan: tuple[Subtask, ...], world: World, skills: dict[int, Skill]
                    ) -> Skill | None:
    """The first subtask's skill when training starts some episodes mid-task, else None."""
    prob = cfg.env.mid_task_init_prob
    if prob <= 0.0:
        return None
    character = world.character
    if not character.can_hold:
        raise ValueError(f"env.mid_task_init_prob: {prob} starts episodes holding an object, which character "
                         f"'{character.name}' cannot; use env.character=puppet or mid_task_init_prob 0")
    first = plan[0]
    skill = next(s for s in skills.values() if s.name == first.skill)
    has_target = first.fixed_target is not None or not skill.mid_task_reads_target
    return skill if has_target and (first.obj >= 0 or first.choices) else None
