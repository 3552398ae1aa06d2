"""The batched long-horizon HSI environment (rsl-rl-lib `VecEnv`).

N independent copies of one compiled scene run in a physics backend (`detach.sim`, chosen by
`sim.backend`). A step reads as: actions -> character -> backend -> skills and plan ->
rewards -> terminations -> resets -> observations, each owned by one object: the character
(`detach.character`), the plan tracker (targets, transitions, scores; the skills of
`detach.skills`), `RewardManager`, `Terminations`, `ResetSampler` and `ObservationBuilder`.
Single-skill tasks are one-subtask plans.

What an evaluator reads: `extras["episode_progress"]` at every step where some episode ended
(`PlanTracker.progress()` of the finished episodes plus each termination, `length`), and
`snapshot(i)`, env i's bodies, subtask, target and path now. Sizes of the observation groups: `obs_spec`.
"""

from __future__ import annotations

import math
import time
from dataclasses import dataclass, replace

import numpy as np
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from detach.character import MovableObject, make_character
from detach.character.body import BODY_NAMES
from detach.config_schema import RunConfig
from detach.envs.observations import ObservationBuilder
from detach.envs.oracle import ORACLE_GROUP, Oracle
from detach.envs.plan_tracker import PlanTracker
from detach.envs.resets import ReferenceSampler, ResetSampler
from detach.envs.rewards import RewardManager
from detach.envs.subtask_starts import RECORD_ENVS, SubtaskStarts, recording_summary, record_subtask_starts
from detach.envs.terminations import Terminations
from detach.host_sync import may_any, rows_at
from detach.sim import make_backend, sim_settings
from detach.sim.raster import Raster
from detach.sim.state import SceneIndex, SimState, read_state
from detach.skills import PlanError, Skill, run_skills
from detach.skills.context import SkillContext, SkillServices
from detach.skills.plan import compile_plan, plan_error_text
from detach.skills.trajectories import TrajectoryReference
from detach.torch_math import quat_from_yaw
from scene_builder.scene import compile_scene


@dataclass(frozen=True)
class EnvSnapshot:
    """One env's state for recording and drawing (world frame; quaternions wxyz)."""

    bodies: tuple[str, ...]
    body_pos: np.ndarray
    body_quat: np.ndarray
    objects: list[dict]
    """Dynamic objects: {"name", "pos", "quat"}."""
    subtask: int
    skill: str
    target: np.ndarray | None = None
    """[3] the current subtask's target (what the task markers draw)."""
    path: np.ndarray | None = None
    """[K, 2] the XY path of the current subtask where its skill follows one (Follow), else None."""
    path_index: float | None = None
    """Where the moving reference point is on `path` (fractional vertex index)."""


class LHEnv(VecEnv):
    """See the module docstring; construct with `make_env`."""

    def __init__(self, cfg: RunConfig, num_envs: int | None = None, device: str | torch.device = "cpu",
                 eval_mode: bool = False, assets: dict | None = None, assets_root=None,
                 verbose: bool = True, seed: int | None = None) -> None:
        ec, sc = cfg.env, sim_settings(cfg.sim)
        self.cfg, self.device, self.eval_mode = cfg, torch.device(device), eval_mode
        self.num_envs = int(num_envs or (cfg.eval.num_envs if eval_mode else sc.num_envs))
        self.gen = torch.Generator(device=self.device).manual_seed(int(cfg.seed if seed is None else seed))
        """Every random draw of task logic, on the env's device (no host round trip on a GPU)."""
        try:
            self.plan = compile_plan(cfg.task)
        except PlanError as exc:
            raise ValueError(plan_error_text(cfg.task, exc)) from None
        self.skills = run_skills(ec.skills, [sub.skill for sub in self.plan])
        """The run's skills: the order of the `task` one-hot and of the plan's skill ids."""
        self.character = make_character(ec.character)
        self.model, self.scene = compile_scene(cfg.task, self.character, sc, assets, assets_root,
                                               camera_height=ec.height_map.camera_height)
        self.backend = make_backend(sc, self.model, self.num_envs, self.device)
        self.index = SceneIndex.build(self.scene, self.device)
        objects = self.scene.objects
        movable = tuple(MovableObject(k, i, objects[i].link_eq, tuple(objects[i].bbox / 2))
                        for k, i in enumerate(self.scene.dynamic))
        self.character.bind(self.num_envs, self.device, self.backend, movable, self.index.hands,
                            self.scene.root_qpos_adr)
        self.dyn_slot = torch.full((len(objects) + 1,), -1, dtype=torch.long, device=self.device)
        """Scene object index -> slot among the dynamic objects (-1: static)."""
        self.dyn_slot[torch.as_tensor(self.scene.dynamic, dtype=torch.long, device=self.device)] = torch.arange(
            len(self.scene.dynamic), device=self.device)
        self.num_actions = self.character.num_actions
        self.substeps, self.dt = int(sc.substeps), sc.physics_dt * sc.substeps
        self.max_episode_length = int(ec.episode_length)
        self.max_transition_steps = int(cfg.eval.max_transition_steps if eval_mode else ec.max_transition_steps)
        r = self.scene.raster
        raster = Raster(torch.as_tensor(r.heights, device=self.device), r.origin, r.spacing)
        trajectory = TrajectoryReference(self.scene.trajectories, ec.trajectory, self.num_envs,
                                         self.max_episode_length, self.max_transition_steps, self.dt, self.device)
        self.services = SkillServices(cfg, self.scene, raster, trajectory, self.gen, self.device, self.dt,
                                      self.max_episode_length, self.max_transition_steps, self.num_envs)
        self.resets = ResetSampler(cfg, self.scene, self.model, self.character, self.gen, self.device)
        self.tracker = PlanTracker(self.plan, self.skills, self.services, self.index, self.resets.rest_z,
                                   self.num_envs)
        self.mid_task_skill = self._mid_task_skill(ec.mid_task_init_prob)
        self.started_mid_task = torch.zeros(self.num_envs, dtype=torch.bool, device=self.device)
        """Episodes that started mid-task or at a later subtask: their success is not the task's,
        so not logged."""
        fixed = self.plan[0].fixed_target
        self.mid_task_target = None if self.mid_task_skill is None else torch.tensor(
            fixed if fixed is not None else [math.nan] * 3, dtype=torch.float32, device=self.device)
        self.subtask_starts = self._record_subtask_starts(ec.subtask_start_prob, assets, assets_root, verbose)
        self.rewards = RewardManager(cfg.rewards, self.plan, self.device, self.skills)
        self.terminations = Terminations(ec, self.tracker.skills)
        self.observations = ObservationBuilder(ec, self.num_envs, self.skills, self.num_actions, raster,
                                               self.index.key.tolist(), self.index.dyn, self.index.obj_half,
                                               self.device)
        self.obs_spec = self.observations.spec
        step_fn = _compiled if sc.compile else (lambda fn: fn)
        self._judge, self._context, self._observe = (step_fn(self._judge_step), step_fn(self.context),
                                                     step_fn(self._observe_step))
        """The step's three groups of tensor work, as `torch.compile` graphs where `sim.compile`."""
        self._oracle: Oracle | None = None
        """Set by `provide_oracle_actions`: the scripted oracle whose action every observation carries."""
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        self.steps = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        """Control steps since the episode started (episode_length_buf may be randomised by a runner)."""
        if verbose:
            print(self.describe())
            if sc.compile:
                print("sim.compile: compiling the env step's three graphs at the first reset and step "
                      "(~1-3 minutes in a fresh process; seconds from torch's cache)", flush=True)
        self.reset()

    def describe(self) -> str:
        """Start-up summary: scene, plan, observation groups and reward terms."""
        sources = self.cfg.task.sample_target_from
        lines = [f"LHEnv '{self.cfg.task.name}': {self.num_envs} envs, character {self.character.name}, "
                 f"{len(self.scene.objects)} objects, dt {self.dt:.4f} s x {self.max_episode_length} steps, "
                 f"{type(self.backend).__name__} on {self.device}",
                 "Plan: " + " -> ".join(f"{s.skill}({sources[s.index]})" for s in self.plan),
                 self.obs_spec.describe(), f"Actions: {self.num_actions}", self.rewards.table()]
        return "\n".join(lines)

    # ---------------------------------------------------------------------------- VecEnv
    def get_observations(self) -> TensorDict:
        return self.obs

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        a = actions.to(self.device, torch.float32).clamp(-1.0, 1.0)
        self.character.pre_step(a, self.state, self.tracker.may_hold())
        self.backend.step(self.character.controls(a, self.backend.qpos), self.substeps)
        ctx, rew, dones, time_outs, ended, log = self._judge(self._read())
        extras: dict = {"time_outs": time_outs, "log": log}
        # The step's one host read, as in IsaacLab's and mjlab's envs: which episodes ended.
        ids = dones.nonzero(as_tuple=False).squeeze(-1)
        if len(ids):
            prog = self.tracker.progress()
            prog.update(ended, length=self.steps.clone())
            extras["episode_progress"] = prog
            extras["log"].update(self.tracker.episode_log(prog, ids, self.terminations.names,
                                                          ~self.started_mid_task[ids]))
            self._reset_envs(ids)
        if len(ids) or may_any(self.tracker.advanced):  # targets changed since the reward: recompute them
            ctx = self._context(self._read() if len(ids) else ctx.state)
        self._ctx = ctx
        self.obs = self._observe(ctx, dones)
        return self.obs, rew, dones, extras

    def _judge_step(self, state: SimState) -> tuple[SkillContext, torch.Tensor, torch.Tensor, torch.Tensor,
                                                     dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """Everything between physics and the step's host read, on the new state: the clocks,
        targets, reward, terminations and transitions. Returns (context, reward, dones,
        time_outs, terminations by name, reward log). No host read (`sim.compile` traces it)."""
        self.episode_length_buf += 1
        self.steps += 1
        ctx = self.context(state)
        rew, parts = self.rewards.compute(ctx)
        ended = self.terminations.compute(ctx)
        last_done = self.tracker.advance(ctx, self.steps)
        bonus = self.rewards.completion_bonus(self.tracker.advanced | last_done, ctx.skill)
        if bonus is not None:
            rew, parts["bonus/subtask_done"] = rew + bonus, bonus
        done_pay = self.rewards.done_pay(self.tracker.subtask)
        if done_pay is not None:
            rew, parts["bonus/subtasks_done"] = rew + done_pay, done_pay
        terminated = torch.stack(list(ended.values())).any(dim=0)
        timeout = self.episode_length_buf >= self.max_episode_length
        time_outs = (timeout | self.terminations.last_subtask_ends(last_done)) & ~terminated
        log = {f"Episode_Reward/{k}": v.nanmean() for k, v in parts.items()}
        return ctx, rew, terminated | time_outs, time_outs, ended, log

    # ---------------------------------------------------------------------------- state
    def _read(self) -> SimState:
        self.state = read_state(self.backend, self.index)
        return self.state

    def context(self, state: SimState | None = None) -> SkillContext:
        """The skills' view of the current state (targets and distances filled in)."""
        return self.tracker.context(self.state if state is None else state, self.steps,
                                    self.character.held_object(), self.character.joint_power_weight)

    def _observe_step(self, ctx: SkillContext, reset: torch.Tensor) -> TensorDict:
        """Observations of ctx; the envs in reset [N] (bool) start their histories afresh."""
        ahead = self.services.trajectory.reference(self.steps, self.observations.sample_times)
        t = self.tracker
        obs = self.observations.build(ctx, reset, ahead, t.follows_path[ctx.skill],
                                      t.hold.float() / self.max_transition_steps,
                                      t.subtask.float() / t.num_subtasks)
        if self._oracle is not None:
            obs[ORACLE_GROUP] = self._oracle(ctx=ctx)
        return obs

    def provide_oracle_actions(self) -> None:
        """From now on every observation carries the group `oracle`: the scripted oracle's
        action [N, A] in the current state. Why: kickstarting compares the student with its
        teachers on the rollout's stored observations, and the oracle reads the true state,
        which only the env has (`train.teachers.SKILL=oracle`, training only; no policy reads
        the group). ValueError for a character the oracle cannot drive."""
        self._oracle = Oracle(self)
        self.obs[ORACLE_GROUP] = self._oracle()

    def _mid_task_skill(self, prob: float) -> Skill | None:
        """The first subtask's skill when training starts some episodes mid-task, else None."""
        if self.eval_mode or prob <= 0.0:
            return None
        if not self.character.can_hold:
            raise ValueError(f"env.mid_task_init_prob: {prob} starts episodes holding an object, which character "
                             f"'{self.character.name}' cannot; use env.character=puppet or mid_task_init_prob 0")
        first = self.plan[0]
        skill = next(s for s in self.tracker.skills.values() if s.name == first.skill)
        has_target = first.fixed_target is not None or not skill.mid_task_reads_target
        return skill if has_target and (first.obj >= 0 or first.choices) else None

    def _record_subtask_starts(self, prob: float, assets, assets_root, verbose: bool) -> SubtaskStarts | None:
        if prob <= 0 or self.eval_mode:
            return None
        if len(self.plan) < 2:
            raise ValueError(f"env.subtask_start_prob: {prob} starts episodes at later subtasks, but task "
                             f"'{self.cfg.task.name}' has one subtask")
        if not self.character.scriptable:
            raise ValueError(f"env.subtask_start_prob: {prob} needs the scripted oracle, which cannot drive "
                             f"character '{self.character.name}'; use env.character=puppet or 0")
        env = self.cfg.env
        quiet = replace(self.cfg, env=replace(env, subtask_start_prob=0.0, mid_task_init_prob=0.0))
        t0 = time.perf_counter()
        starts = record_subtask_starts(LHEnv(quiet, num_envs=RECORD_ENVS, device=self.device, assets=assets,
                                             assets_root=assets_root, verbose=False, seed=int(self.cfg.seed) + 1))
        if verbose or len(starts) == 0:
            print(recording_summary(starts, len(self.plan), time.perf_counter() - t0)
                  + ("; no episode starts at a later subtask" if len(starts) == 0 else ""), flush=True)
        if len(starts) == 0:
            return None
        _ = starts.by_subtask  # built here: it reads the device, which a step's `draw` must not
        return starts

    def _start_at_later_subtasks(self, ids: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor,
                                 root_xy: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """Turn a share `env.subtask_start_prob` of the starts of envs ids that did not start
        mid-task into recorded subtask starts (qpos, qvel, root_xy changed in place). Returns
        (late [n] bool: the rows of ids that start so, the recorded state drawn for every row)."""
        draw = torch.rand(len(ids), generator=self.gen, device=self.gen.device).to(self.device)
        late = (draw < self.cfg.env.subtask_start_prob) & ~self.started_mid_task[ids]
        starts = self.subtask_starts
        pick = starts.draw(len(ids), self.gen)
        rows = late[:, None]
        qpos.copy_(torch.where(rows, starts.qpos[pick], qpos))
        qvel.copy_(torch.where(rows, starts.qvel[pick], qvel))
        root_xy.copy_(torch.where(rows, starts.root_pos[pick, :2], root_xy))
        self.tracker.objects[ids] = torch.where(rows, starts.objects[pick], self.tracker.objects[ids])
        self.started_mid_task[ids] |= late
        return late, pick

    def _reset_envs(self, ids: torch.Tensor) -> None:
        """New episodes in envs ids; selections within them are masks (no host read)."""
        qpos, qvel, root_xy = self.resets.sample(ids)
        self.tracker.draw_objects(ids)
        self.started_mid_task.index_fill_(0, ids, False)  # not `[ids] = False`: no host-to-device copy
        holds = []  # (slot [n], -1 where none; pelvis pos, quat; object pos, quat)
        if self.mid_task_skill is not None:
            mid = self.resets.mid_task(ids, self.tracker.objects[ids, 0], self.mid_task_skill, self.mid_task_target,
                                       self.index.obj_half, qpos, qvel, root_xy)
            if mid is not None:
                pick, start = mid
                self.started_mid_task[ids] = pick
                slot = torch.where(pick & start.held, self.dyn_slot[self.tracker.objects[ids, 0]], -1)
                root = torch.cat((start.root_xy, start.height[:, None]), -1)
                holds.append((slot, root, quat_from_yaw(start.yaw), start.obj_pos, start.obj_quat))
        late = None if self.subtask_starts is None else self._start_at_later_subtasks(ids, qpos, qvel, root_xy)
        if late is not None:
            st, (rows, pick) = self.subtask_starts, late
            holds.append((torch.where(rows, st.held[pick], -1), st.root_pos[pick], st.root_quat[pick],
                          st.held_pos[pick], st.held_quat[pick]))
        self.backend.reset(ids, qpos, qvel)
        self.episode_length_buf.index_fill_(0, ids, 0)
        self.steps.index_fill_(0, ids, 0)
        self.character.reset(ids)
        for slot, *pose in holds:
            if self.character.can_hold and may_any(slot >= 0):
                self.character.hold(ids, slot, *pose)
        xy = rows_at(self.num_envs, ids, root_xy)
        self.tracker.reset(ids, self.steps, xy)
        if late is not None:
            rows, pick = late
            self.tracker.begin_at(ids, rows, self.subtask_starts.subtask[pick], self.steps, xy)

    def reset(self, ids: torch.Tensor | None = None) -> TensorDict:
        """Start new episodes in envs ids (all by default); returns the observations."""
        ids = torch.arange(self.num_envs, device=self.device) if ids is None else ids
        self._reset_envs(ids)
        every = torch.ones_like(ids, dtype=torch.bool)
        self._ctx = self._context(self._read())
        self.obs = self._observe(self._ctx, rows_at(self.num_envs, ids, every, False))
        return self.obs

    def set_reference_sampler(self, fn: ReferenceSampler) -> None:
        """Reference-state initialisation source (`env.init` random/mixed), e.g. the motion
        library; see `detach.envs.resets` for the expected callable."""
        self.resets.reference_sampler = fn

    # ---------------------------------------------------------------------------- views
    def snapshot(self, i: int = 0) -> EnvSnapshot:
        """Env i's character bodies, dynamic objects, current subtask, its target and (Follow)
        its path with the reference point's place on it."""
        st = self.state
        objects = [{"name": self.scene.objects[o].name, "pos": st.obj_pos[i, o].tolist(),
                    "quat": st.obj_quat[i, o].tolist()} for o in self.scene.dynamic]
        sub = int(self.tracker.subtask[i])
        ctx = getattr(self, "_ctx", None)
        target = None if ctx is None else ctx.target[i].detach().cpu().numpy().astype(np.float64)
        path = index = None
        if bool(self.tracker.follows_path[int(self.tracker.tensors.skill[min(sub, len(self.plan) - 1)])]):
            path, index = self._path_of(i)
        return EnvSnapshot(BODY_NAMES, st.body_pos[i].cpu().numpy(), st.body_quat[i].cpu().numpy(), objects,
                           sub, self.plan[min(sub, len(self.plan) - 1)].skill, target, path, index)

    def _path_of(self, i: int) -> tuple[np.ndarray, float]:
        """Env i's reference path without its padding (repeats of the last vertex) and where
        its reference point is now, as a fractional vertex index."""
        traj = self.services.trajectory
        verts = traj.verts[i].detach().cpu().numpy().astype(np.float64)
        moved = np.any(np.abs(verts - verts[-1]) > 1e-9, axis=1)
        last = int(np.nonzero(moved)[0][-1]) + 1 if moved.any() else 0
        verts = verts[: last + 1]
        t = float(self.steps[i] - traj.t0[i]) * self.dt
        return verts, float(np.clip(t / float(traj.vertex_dt[i]), 0.0, len(verts) - 1))


def _compiled(fn):
    """fn as a `torch.compile` graph of fixed shapes (N never changes within an env)."""
    return torch.compile(fn, dynamic=False)


def make_env(run_cfg: RunConfig, num_envs: int | None = None, device: str | torch.device = "cpu",
             eval_mode: bool = False, **kw) -> LHEnv:
    """The env of a resolved run configuration (`detach.config.resolve`)."""
    return LHEnv(run_cfg, num_envs=num_envs, device=device, eval_mode=eval_mode, **kw)
