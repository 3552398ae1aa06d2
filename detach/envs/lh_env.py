"""The batched long-horizon HSI environment (rsl-rl-lib `VecEnv`): it orchestrates, others do.

N copies of one scene run in a physics backend (`World`). A step reads as: actions ->
character -> backend -> plan tracker (targets, transitions, scores; the skills of
`detach.skills`) -> `RewardManager` (terms and bonuses) -> `Terminations` -> new episodes
where some ended (`EpisodeStarts` plans them, the plan tracker keeps their books) ->
`ObservationBuilder`. Single-skill tasks are one-subtask plans.

Evaluators read `extras["episode_progress"]` and `snapshot(i)`; group sizes are in `obs_spec`.
"""

from __future__ import annotations

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from detach.config.schema import RunConfig
from detach.envs.observations import ObservationBuilder
from detach.envs.oracle import ORACLE_GROUP, Oracle
from detach.envs.plan_tracker import PlanTracker
from detach.envs.resets import ReferenceSampler, ResetSampler
from detach.envs.rewards import RewardManager
from detach.envs.starts import EpisodeStarts
from detach.envs.subtask_starts import SubtaskStarts
from detach.envs.terminations import Terminations
from detach.envs.views import describe, snapshot
from detach.envs.world import World
from detach.host_sync import may_any, rows_at
from detach.sim import sim_settings
from detach.sim.state import SimState
from detach.skills import run_skills
from detach.skills.context import SkillContext, SkillServices
from detach.skills.plan import compile_plan
from detach.skills.trajectories import TrajectoryReference


class LHEnv(VecEnv):
    """See the module docstring; construct with `make_env`."""

    def __init__(self, cfg: RunConfig, num_envs: int | None = None, device: str | torch.device = "cpu",
                 eval_mode: bool = False, assets: dict | None = None, assets_root=None, verbose: bool = True,
                 seed: int | None = None, subtask_starts: SubtaskStarts | None = None) -> None:
        ec, sc = cfg.env, sim_settings(cfg.sim)
        self.cfg, self.device, self.eval_mode = cfg, torch.device(device), eval_mode
        self.num_envs = int(num_envs or (cfg.eval.num_envs if eval_mode else sc.num_envs))
        self.gen = torch.Generator(device=self.device).manual_seed(int(cfg.seed if seed is None else seed))
        """Every random draw of task logic, on the env's device (no host round trip on a GPU)."""
        self.plan = compile_plan(cfg.task)  # checked with file and line before: detach.train.run_config
        self.skills = run_skills(ec.skills, [sub.skill for sub in self.plan])  # one-hot and skill-id order
        self.world = world = World.build(cfg, sc, self.num_envs, self.device, assets, assets_root)
        self.character, self.model, self.scene, self.backend = world.character, world.model, world.scene, world.backend
        self.index, self.num_actions = world.index, self.character.num_actions
        self.substeps, self.dt = int(sc.substeps), sc.physics_dt * sc.substeps
        self.max_episode_length = int(ec.episode_length)
        self.max_transition_steps = int(cfg.eval.max_transition_steps if eval_mode else ec.max_transition_steps)
        trajectory = TrajectoryReference(self.scene.trajectories, ec.trajectory, self.num_envs,
                                         self.max_episode_length, self.max_transition_steps, self.dt, self.device)
        self.services = SkillServices(cfg, self.scene, world.raster, trajectory, self.gen, self.device, self.dt,
                                      self.max_episode_length, self.max_transition_steps, self.num_envs)
        self.resets = ResetSampler(cfg, self.scene, self.model, self.character, self.gen, self.device)
        self.tracker = PlanTracker(self.plan, self.skills, self.services, self.index, self.resets.rest_z,
                                   self.num_envs)
        self.starts = EpisodeStarts(cfg, self.plan, world, self.resets, self.tracker.skills, subtask_starts, eval_mode)
        self.subtask_starts = self.starts.recorded
        self.rewards = RewardManager(cfg.rewards, self.plan, self.device, self.skills)
        self.terminations = Terminations(ec, self.tracker.skills)
        self.observations = ObservationBuilder(ec, self.num_envs, self.skills, self.num_actions,
                                               world.raster, self.index.key.tolist(), self.index.dyn,
                                               self.index.obj_half, self.device)
        self.obs_spec = self.observations.spec
        if verbose:
            print(describe(self), flush=True)
        self._judge, self._context, self._observe = _graphs(sc.compile, verbose, self._judge_step, self.context,
                                                            self._observe_step)
        """The step's three groups of tensor work, as `torch.compile` graphs where `sim.compile`."""
        self._oracle: Oracle | None = None
        """Set by `provide_oracle_actions`: the scripted oracle whose action every observation carries."""
        self.episode_length_buf = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        self.steps = torch.zeros(self.num_envs, dtype=torch.long, device=self.device)
        """Control steps since the episode started (episode_length_buf may be randomised by a runner)."""
        self.reset()

    def get_observations(self) -> TensorDict:
        return self.obs

    def step(self, actions: torch.Tensor) -> tuple[TensorDict, torch.Tensor, torch.Tensor, dict]:
        self._actuate(actions)
        ctx, rew, dones, extras, ended = self._judge(self._read())
        ids = dones.nonzero(as_tuple=False).squeeze(-1)  # the step's one host read: which episodes ended
        if len(ids):
            self._end_episodes(ids, ended, extras)
        self.obs = self._observe(self._current(ctx, bool(len(ids))), dones)
        return self.obs, rew, dones, extras

    def _actuate(self, actions: torch.Tensor) -> None:
        """Actions [N, A] in [-1, 1] -> the character's controls -> the backend's substeps."""
        a = actions.to(self.device, torch.float32).clamp(-1.0, 1.0)
        self.character.pre_step(a, self.state, self.tracker.may_hold())
        self.world.assist.apply(self.state)  # a training aid, off unless set (`train.balance_assist`)
        self.backend.step(self.character.controls(a, self.backend.qpos), self.substeps)

    def _judge_step(self, state: SimState) -> tuple[SkillContext, torch.Tensor, torch.Tensor, dict,
                                                     dict[str, torch.Tensor]]:
        """Everything between physics and the step's host read, on the new state: the clocks,
        targets, reward, terminations and transitions. Returns (context, reward, dones, extras
        {time_outs, reward log}, terminations by name). No host read (`sim.compile` traces it)."""
        self.episode_length_buf += 1
        self.steps += 1
        ctx = self.context(state)
        rew, parts = self.rewards.compute(ctx)
        ended = self.terminations.compute(ctx)
        last_done = self.tracker.advance(ctx, self.steps)
        rew = self.rewards.add_bonuses(rew, parts, self.tracker.advanced | last_done, ctx.skill, self.tracker.subtask)
        dones, time_outs = self.terminations.outcome(ended, self.episode_length_buf >= self.max_episode_length,
                                                     last_done)
        return ctx, rew, dones, {"time_outs": time_outs, "log": self.rewards.log(parts)}, ended

    def _end_episodes(self, ids: torch.Tensor, ended: dict[str, torch.Tensor], extras: dict) -> None:
        """The finished episodes ids into extras (progress, training log), then new ones there."""
        progress, log = self.tracker.episode_end(ids, ended, self.steps, self.terminations.names)
        extras["episode_progress"] = progress
        extras["log"].update(log)
        self._reset_envs(ids)

    def _current(self, ctx: SkillContext, reset: bool) -> SkillContext:
        """ctx again where targets changed since the reward: some envs reset or moved on."""
        if reset or may_any(self.tracker.advanced):
            ctx = self._context(self._read() if reset else ctx.state)
        self._ctx = ctx
        return ctx

    def _read(self) -> SimState:
        self.state = self.world.read()
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
        """From now on every observation carries the group `oracle`, the scripted oracle's action
        [N, A] now: kickstarting compares the student with its teachers on stored observations,
        and only the env has the true state the oracle reads (`train.teachers.SKILL=oracle`)."""
        self._oracle = Oracle(self)
        self.obs[ORACLE_GROUP] = self._oracle()

    def _reset_envs(self, ids: torch.Tensor) -> None:
        """New episodes in envs ids, as `EpisodeStarts` plans them (no host read)."""
        start = self.starts.plan(ids, self.tracker.draw_objects)
        self.backend.reset(ids, start.qpos, start.qvel)
        self.episode_length_buf.index_fill_(0, ids, 0)  # not `[ids] = 0`: no host-to-device copy
        self.steps.index_fill_(0, ids, 0)
        self.character.reset(ids)
        for hold in start.holds:
            if self.character.can_hold and may_any(hold.slot >= 0):
                self.character.hold(ids, hold.slot, hold.root_pos, hold.root_quat, hold.obj_pos, hold.obj_quat)
        self.tracker.reset(ids, self.steps, start)

    def reset(self, ids: torch.Tensor | None = None) -> TensorDict:
        """Start new episodes in envs ids (all by default); returns the observations."""
        ids = torch.arange(self.num_envs, device=self.device) if ids is None else ids
        self._reset_envs(ids)
        every = torch.ones_like(ids, dtype=torch.bool)
        self._ctx = self._context(self._read())
        self.obs = self._observe(self._ctx, rows_at(self.num_envs, ids, every, False))
        return self.obs

    def set_reference_sampler(self, fn: ReferenceSampler) -> None:
        """Reference states for `env.init` random/mixed (the motion library's; `detach.envs.resets`)."""
        self.resets.reference_sampler = fn

    describe, snapshot = describe, snapshot  # the start-up summary; snapshot(i): env i now (detach.envs.views)


def _graphs(compile: bool, verbose: bool, *fns):
    """fns, as `torch.compile` graphs of fixed shapes where compile (N never changes in an env)."""
    if compile and verbose:
        print("sim.compile: compiling the env step's three graphs at the first reset and step "
              "(~1-3 minutes in a fresh process; seconds from torch's cache)", flush=True)
    return tuple(torch.compile(fn, dynamic=False) if compile else fn for fn in fns)


def make_env(run_cfg: RunConfig, num_envs: int | None = None, device: str | torch.device = "cpu",
             eval_mode: bool = False, **kw) -> LHEnv:
    """The env of a resolved run configuration (`detach.config.resolve`); a training env with
    `env.subtask_start_prob` takes its recorded starts (`subtask_starts`) from the train layer."""
    return LHEnv(run_cfg, num_envs=num_envs, device=device, eval_mode=eval_mode, **kw)
