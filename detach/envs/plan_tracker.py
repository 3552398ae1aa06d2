"""Each env's progress through the plan: current subtask, transitions, statistics, scores.

Transition rule (the paper's): a subtask is complete once its skill's anchor-to-target
distance stays <= `success_threshold` (0.3 m) for `max_transition_steps` consecutive control
steps (60 in training, 20 in evaluation); the next subtask then starts at once. Every skill
of the plan (`detach.skills`) supplies its target, distance, statistics and score; this
object owns the per-env bookkeeping and builds the per-step `SkillContext`.

What an evaluator reads (`progress()`): per env the current `subtask`; per env and subtask
`done` (transition fired), `score` (the skill's success score), `start` / `end` (control steps
since the episode start, -1 if not reached), `exec_time` (s), the skills' statistics (e.g.
`grasped`, `on_path`, `path_steps`), and `lh_success` (every subtask scored 1).
"""

from __future__ import annotations

import torch

from detach.envs.starts import StartPlan
from detach.host_sync import may_any, rows_at
from detach.sim.state import SceneIndex, SimState
from detach.skills import Skill, Subtask, skill_class
from detach.skills.context import SkillContext, SkillServices
from detach.skills.plan import PlanTensors


class PlanTracker:
    def __init__(self, plan: tuple[Subtask, ...], skills: tuple[str, ...], services: SkillServices,
                 index: SceneIndex, rest_z: torch.Tensor, num_envs: int) -> None:
        self.plan, self.services, self.index, self.rest_z = plan, services, index, rest_z
        d, n, s = services.device, num_envs, len(plan)
        self.tensors = PlanTensors.build(plan, skills, d)
        names = skills
        present = {sub.skill for sub in plan}
        self.skills: dict[int, Skill] = {}
        """Index in the run's skills (`LHEnv.skills`) -> bound skill, for the skills of this plan."""
        for i, name in enumerate(names):
            if name in present:
                self.skills[i] = skill_class(name)()
                self.skills[i].bind(plan, services)
        self.follows_path = torch.tensor([skill_class(name).follows_path for name in names], device=d)
        self.holds_objects = torch.tensor([skill_class(name).holds_objects for name in names], device=d)
        self.num_subtasks = s
        z = lambda *shape, dtype=torch.long: torch.zeros(*shape, dtype=dtype, device=d)  # noqa: E731
        self.subtask, self.hold = z(n), z(n)
        self.begin = z(n)
        """[N] the subtask each env's episode began at (`begin_at`), 0 by default."""
        self.done = z(n, s, dtype=torch.bool)
        self.start_step, self.end_step = z(n, s) - 1, z(n, s) - 1
        self.stats = {k: z(n, s, dtype=dt) for sk in self.skills.values() for k, dt in sk.stats.items()}
        self.advanced = torch.zeros(n, dtype=torch.bool, device=d)
        """[N] the envs whose subtask changed at the last `advance`."""
        self.objects = self.tensors.obj.expand(n, s).clone()
        """[N, S] each env's object of every subtask (drawn at reset where the plan gives choices)."""
        self.started_mid_task = torch.zeros(n, dtype=torch.bool, device=d)
        """[N] episodes that started mid-task or at a later subtask: their success is not the
        plan's, so not logged as such (`episode_end`)."""
        self.choices = {i: torch.tensor(sub.choices, device=d) for i, sub in enumerate(plan) if sub.choices}
        self._now_and_next = torch.tensor([0.0, services.dt], device=d)

    # ------------------------------------------------------------------ per step
    def may_hold(self) -> torch.Tensor:
        """[N] bool: the current subtask's skill lets the character hold objects."""
        return self.holds_objects[self.tensors.skill[self.subtask]]

    def context(self, st: SimState, steps: torch.Tensor, held: torch.Tensor, joint_power_weight: float
                ) -> SkillContext:
        """The skills' view of this step, with each env's target and distance filled in."""
        sub, plan = self.subtask, self.tensors
        n, dev = len(sub), self.services.device
        obj = self.objects[torch.arange(n, device=dev), sub]
        if self.index.obj_body.numel():
            oc = obj.clamp(min=0)
            ar = torch.arange(n, device=dev)
            opos, oquat, olin = st.obj_pos[ar, oc], st.obj_quat[ar, oc], st.obj_lin[ar, oc]
            half = self.index.obj_half[oc]
        else:
            opos = olin = half = torch.zeros(n, 3, device=dev)
            oquat = torch.zeros(n, 4, device=dev)
            oquat[:, 0] = 1.0
        dt = self.services.dt
        now_and_next = self.services.trajectory.reference(steps, self._now_and_next)  # one sample, not two
        ref = now_and_next[:, 0]
        dyn = self.index.dyn
        ctx = SkillContext(
            services=self.services, state=st, skill=plan.skill[sub], subtask=sub, obj=obj, obj_pos=opos,
            obj_quat=oquat, obj_lin=olin, obj_half=half, obj_rest_z=self.rest_z[obj],
            fixed_target=plan.fixed_target[sub], has_fixed=plan.has_fixed[sub], held=held, steps=steps,
            joint_power=st.joint_power * joint_power_weight,
            dyn_speed=st.obj_lin[:, dyn].norm(dim=-1) if len(dyn) else torch.zeros(n, 0, device=dev),
            ref_xy=ref, ref_vel=(now_and_next[:, 1] - ref) / dt)
        target = torch.zeros(n, 3, device=dev)
        for i, skill in self.skills.items():
            target = torch.where((ctx.skill == i)[:, None], skill.target(ctx), target)
        ctx.target = target
        goal = target
        for i, skill in self.skills.items():
            if type(skill).goal is not Skill.goal:
                goal = torch.where((ctx.skill == i)[:, None], skill.goal(ctx), goal)
        ctx.goal = goal
        dist = torch.zeros(n, device=dev)
        for i, skill in self.skills.items():
            dist = torch.where(ctx.skill == i, skill.distance(ctx), dist)
        ctx.dist = dist
        return ctx

    def advance(self, ctx: SkillContext, steps: torch.Tensor) -> torch.Tensor:
        """Accumulate statistics and hold counters; fire transitions. Returns bool [N]: the
        last subtask completed at this step. `advanced` [N] marks the envs whose subtask
        changed. Reads nothing on the host where that is not free (`detach.host_sync`)."""
        for i, skill in self.skills.items():
            active = ctx.skill == i
            if may_any(active):
                skill.update_stats(ctx, active, self.stats)
        ar, sub = torch.arange(len(steps), device=steps.device), self.subtask
        self.hold = torch.where(ctx.dist <= self.services.cfg.env.success_threshold, self.hold + 1,
                                torch.zeros_like(self.hold))
        complete = self.hold >= self.services.max_transition_steps
        self.done[ar, sub] |= complete
        self.end_step[ar, sub] = torch.where(complete, steps, self.end_step[ar, sub])
        last = sub == self.num_subtasks - 1
        self.advanced = complete & ~last
        if may_any(self.advanced):
            self.subtask += self.advanced.long()
            self.hold.masked_fill_(self.advanced, 0)
            self.start(self.advanced, steps, ctx.state.root_pos[:, :2])
        return complete & last

    def start(self, mask: torch.Tensor, steps: torch.Tensor, root_xy: torch.Tensor) -> None:
        """Stamp the start of the current subtask of the envs in mask [N] and let its skill set
        it up (steps [N], root_xy [N, 2]: every env's; only the masked rows are used)."""
        ar, sub = torch.arange(len(mask), device=mask.device), self.subtask
        self.start_step[ar, sub] = torch.where(mask, steps, self.start_step[ar, sub])
        self.services.trajectory.restart(mask, steps)
        skill = self.tensors.skill[sub]
        for i, s in self.skills.items():
            m = mask & (skill == i)
            if may_any(m):
                s.start(m, sub, root_xy)
        park = mask & ~self.follows_path[skill]
        if may_any(park):
            self.services.trajectory.park(park, root_xy)

    def draw_objects(self, ids: torch.Tensor) -> torch.Tensor:
        """[n, S] the objects of new episodes in envs ids: each subtask with choices draws one."""
        objects = self.objects[ids]
        for i, options in self.choices.items():
            gen = self.services.generator
            pick = torch.randint(len(options), (len(ids),), generator=gen, device=gen.device).to(options.device)
            objects[:, i] = options[pick]
        return objects

    def reset(self, ids: torch.Tensor, steps: torch.Tensor, start: StartPlan) -> None:
        """New episodes in envs ids start as `start` says: its objects, its first subtask or a
        later one (steps [N]: every env's)."""
        self.objects[ids] = start.objects
        self.started_mid_task[ids] = start.started_later
        # index_fill_ takes the value as a kernel argument; `t[ids] = 0` copies it to the device
        for t, value in ((self.subtask, 0), (self.begin, 0), (self.hold, 0), (self.done, False), (self.start_step, -1),
                         (self.end_step, -1), *((v, 0) for v in self.stats.values())):
            t.index_fill_(0, ids, value)
        every = torch.ones_like(ids, dtype=torch.bool)
        root_xy = rows_at(len(self.subtask), ids, start.root_xy)
        self.start(rows_at(len(self.subtask), ids, every, False), steps, root_xy)
        if start.begins_later is not None:
            self.begin_at(ids, start.begins_later, start.begin_subtask, steps, root_xy)

    def begin_at(self, ids: torch.Tensor, late: torch.Tensor, sub: torch.Tensor, steps: torch.Tensor,
                 root_xy: torch.Tensor) -> None:
        """The rows of envs ids (just reset) where late [n] is set begin at subtask sub [n] >= 1
        instead of 0, the earlier subtasks counted as done (`env.subtask_start_prob`); steps,
        root_xy as for `reset`."""
        sub = torch.where(late, sub, self.subtask[ids])
        self.subtask[ids] = sub
        self.begin[ids] = sub
        before = torch.arange(self.num_subtasks, device=sub.device)[None, :] < sub[:, None]
        self.done[ids] = torch.where(late[:, None], before, self.done[ids])
        mask = rows_at(len(self.subtask), ids, late, False)
        if may_any(mask):
            self.start(mask, steps, root_xy)

    # ------------------------------------------------------------------ results
    def scores(self) -> torch.Tensor:
        """[N, S] success score of every subtask (0 for those not reached)."""
        sk = self.tensors.skill[None, :].expand_as(self.done)
        out = self.done.float()
        for i, skill in self.skills.items():
            out = torch.where(sk == i, skill.score(self.done, self.stats), out)
        return out

    def progress(self) -> dict[str, torch.Tensor]:
        """Per-env plan progress (clones); see the module docstring."""
        scores = self.scores()
        span = (self.end_step - self.start_step).float() * self.services.dt
        return dict(subtask=self.subtask.clone(), done=self.done.clone(), score=scores,
                    start=self.start_step.clone(), end=self.end_step.clone(),
                    exec_time=torch.where(self.end_step >= 0, span, torch.full_like(span, float("nan"))),
                    lh_success=(scores >= 1.0).all(dim=-1), **{k: v.clone() for k, v in self.stats.items()})

    def episode_end(self, ids: torch.Tensor, ended: dict[str, torch.Tensor], length: torch.Tensor,
                    terminations: tuple[str, ...]) -> tuple[dict[str, torch.Tensor], dict[str, torch.Tensor]]:
        """(progress of every env with its terminations ended and episode `length` [N], the
        training log of the finished episodes ids), read before ids reset."""
        prog = self.progress()
        prog.update(ended, length=length.clone())
        return prog, self.episode_log(prog, ids, terminations, ~self.started_mid_task[ids])

    def episode_log(self, prog: dict[str, torch.Tensor], ids: torch.Tensor,
                    terminations: tuple[str, ...], counted: torch.Tensor | None = None
                    ) -> dict[str, torch.Tensor]:
        """Values of the finished episodes ids for the training log, named as IsaacLab's envs
        name theirs for rsl-rl (`Episode_Termination/`, `Episode_Success/`; docs/METRICS.md).
        `Episode_Success/lh` counts the rows of ids where counted [n] is set (default all; the
        env leaves out episodes that started mid-task or at a later subtask); subtask i's
        success counts the episodes that began at or before it (`begin`), left out at i = 0
        where counted is unset (a held start's grasp scores from its first step), so a later
        subtask's curve includes the episodes that began there. Rows not counted are NaN, which
        the training log skips (a selection would need a host read). The episode length is
        rsl-rl's own `Train/mean_episode_length`."""
        log = {f"Episode_Termination/{name}": prog[name][ids].float() for name in terminations}
        counted = torch.ones_like(ids, dtype=torch.bool) if counted is None else counted
        log["Episode_Success/lh"] = torch.where(counted, prog["lh_success"][ids].float(), torch.nan)
        begin = self.begin[ids]
        for i, s in enumerate(self.plan):
            count = (begin <= i) & (counted | (i > 0))
            log[f"Episode_Success/{i}_{s.skill}"] = torch.where(count, prog["score"][ids, i], torch.nan)
        return log
