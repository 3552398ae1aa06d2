"""Follow: walk along a reference trajectory (TokenHSI's `traj`; the paper's "Follow").

Target: `traj_K` (trajectory K of the task YAML, walked at the generator's mean speed) or
`traj_rand` (a procedural path per episode starting at the pelvis); the subtask's target is
the path's last vertex (z = 0) and its distance the pelvis's XY distance to it.
Success (the paper): the end was reached (the transition fired) and the pelvis stayed within
`success_threshold` of the path (XY) for at least `env.follow_on_path_frac` of the subtask's
steps. Termination: the pelvis more than `env.traj_fail_distance` from the reference point.
Rewards: position and precision kernels on the error to the moving reference point and a
velocity-tracking term; an opt-in kernel on the distance to the path (`on_path`, weight 0).
"""

from __future__ import annotations

import torch

from detach.host_sync import may_any
from detach.skills.base import RAND, PlanError, RewardTerm, Skill, Subtask
from detach.skills.context import OracleCommand, SkillContext
from detach.skills.registry import register_skill
from detach.skills.trajectories import distance_to_polyline

TRACK_GAIN = 2.0
"""Velocity (m/s) asked per metre of error toward the reference (1/s), on top of the
reference's own velocity; a 0.5 s time constant."""
TRACK_MAX_SPEED = 2.0
"""The asked velocity is capped at this speed (m/s): catching up at a brisk walk."""


def _ref_error(ctx: SkillContext) -> torch.Tensor:
    """[N, 2] XY vector from the pelvis to the trajectory's reference point."""
    return ctx.ref_xy - ctx.state.root_pos[:, :2]


def position(ctx: SkillContext) -> torch.Tensor:
    d2 = _ref_error(ctx).pow(2).sum(-1)
    return torch.exp(-2.0 * d2)


def precision(ctx: SkillContext) -> torch.Tensor:
    """A narrow kernel exp(-20 d^2) (0.17 at the 0.3 m success threshold): exp(-2 d^2) alone
    is nearly flat there and leaves the character trailing its reference by ~0.6 m."""
    d2 = _ref_error(ctx).pow(2).sum(-1)
    return torch.exp(-20.0 * d2)


def on_path(ctx: SkillContext) -> torch.Tensor:
    """exp(-20 d^2) of the pelvis's XY distance to the path itself (0.17 at the 0.3 m success
    threshold): the success rule measures the path, the other terms the moving reference
    point, which a policy may trail or lead while on the path, or match while cutting a corner
    (LH1's doorway). Weight 0 unless `+rewards.terms.follow/on_path=W` sets one."""
    d = distance_to_polyline(ctx.state.root_pos[:, :2], ctx.services.trajectory.verts)
    return torch.exp(-20.0 * d * d)


def velocity(ctx: SkillContext) -> torch.Tensor:
    """Velocity tracking: the asked velocity is the reference's own plus `TRACK_GAIN` times the
    error toward it (capped at `TRACK_MAX_SPEED`); dense at any distance, and it asks the
    character to stop on the end point once the reference has stopped there."""
    want = ctx.ref_vel + TRACK_GAIN * _ref_error(ctx)
    speed = want.norm(dim=-1, keepdim=True)
    want = want * (TRACK_MAX_SPEED / speed.clamp(min=TRACK_MAX_SPEED))
    err2 = ((ctx.state.body_lin[:, 0, :2] - want) ** 2).sum(-1)
    return torch.exp(-0.5 * err2)


@register_skill
class Follow(Skill):
    name = "follow"
    aliases = ("traj",)
    display_name = "Follow"
    color = (46, 160, 67)
    motion_labels = ("walk", "turn", "idle")
    sources = ("traj",)
    follows_path = True
    task_observation = ("target", "path", "height_map")
    stats = {"on_path": torch.long, "path_steps": torch.long}
    termination_names = ("traj_failed",)
    reward_terms = {"position": RewardTerm(position, 0.4), "precision": RewardTerm(precision, 0.3),
                    "velocity": RewardTerm(velocity, 0.3), "on_path": RewardTerm(on_path, 0.0)}

    def compile_entry(self, index, source, ref, obj, task) -> Subtask:
        if source != "traj":
            raise PlanError(("sample_target_from", index),
                            f"'{self.name}' needs traj_K or traj_rand, found {source}_{ref}")
        if ref == RAND:
            return Subtask(index, self.name, source, RAND)
        last = task.trajectories[ref][-1]
        return Subtask(index, self.name, source, ref, fixed_target=(float(last[0]), float(last[1]), 0.0))

    def bind(self, plan, services) -> None:
        super().bind(plan, services)
        self.traj_id = torch.tensor([s.ref if s.skill == self.name else -2 for s in plan], device=self.device)
        self.random_paths = any(s.skill == self.name and s.ref == RAND for s in plan)

    def start(self, mask: torch.Tensor, subtask: torch.Tensor, root_xy: torch.Tensor) -> None:
        traj = self.services.trajectory
        tid = self.traj_id[subtask]
        rand = mask & (tid == RAND)
        if self.random_paths and may_any(rand):
            traj.load_random(rand, root_xy, self.services.generator)
        for k in traj.fixed:
            sel = mask & (tid == k)
            if may_any(sel):
                traj.load_fixed(sel, k)

    def target(self, ctx: SkillContext) -> torch.Tensor:
        end = self.services.trajectory.end
        return torch.cat((end, torch.zeros(len(end), 1, device=end.device)), dim=-1)

    def distance(self, ctx: SkillContext) -> torch.Tensor:
        return (ctx.state.root_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1)

    def update_stats(self, ctx, active, stats) -> None:
        ar = torch.arange(ctx.num_envs, device=self.device)
        on = distance_to_polyline(ctx.state.root_pos[:, :2], self.services.trajectory.verts) \
            <= self.services.cfg.env.success_threshold
        stats["path_steps"][ar, ctx.subtask] += active.long()
        stats["on_path"][ar, ctx.subtask] += (active & on).long()

    def score(self, done, stats) -> torch.Tensor:
        frac = stats["on_path"].float() / stats["path_steps"].clamp(min=1).float()
        return (done & (frac >= self.services.cfg.env.follow_on_path_frac)).float()

    def terminations(self, ctx: SkillContext) -> dict[str, torch.Tensor]:
        far = (ctx.state.root_pos[:, :2] - ctx.ref_xy).norm(dim=-1) > self.services.cfg.env.traj_fail_distance
        return {"traj_failed": far}

    def oracle(self, ctx: SkillContext, cmd: OracleCommand, active: torch.Tensor) -> None:
        """Track the moving reference point: feed-forward velocity + proportional correction."""
        vt = ctx.ref_vel + 3.0 * (ctx.ref_xy - ctx.state.root_pos[:, :2])
        cmd.velocity = torch.where(active[:, None], vt, cmd.velocity)
        moving = vt.norm(dim=-1) > 0.3
        cmd.yaw_target = torch.where(active & moving, torch.atan2(vt[:, 1], vt[:, 0]), cmd.yaw_target)

