"""Reward terms (mjlab style): small named functions, weights from the task YAML.

Every skill has its own terms, named `<skill>/<term>`, each in [0, 1] with an exp kernel in
the style of TokenHSI/AMP HSI tasks; only the current subtask's terms are paid. Two penalties
apply always: `penalty/power` = -power_coeff * sum |torque * joint velocity| over the 32
hinges (W), and `penalty/dyn_obj_speed` = -coeff * sum over dynamic objects of
max(0, speed - threshold) (m/s) to discourage kicking or throwing boxes. `RewardManager`
prints a table of active terms with their weights at start-up.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import torch

from detach.config_schema import SKILLS, RewardsCfg

TAR_SPEED = 1.5
"""Desired approach speed (m/s) of the velocity terms."""
NEAR = 0.5
"""Within this XY distance (m) of its goal an approach term pays its maximum."""
TRACK_GAIN = 2.0
"""Follow: velocity (m/s) asked per metre of error toward the reference (1/s), on top of the
reference's own velocity; a 0.5 s time constant."""
TRACK_MAX_SPEED = 2.0
"""Follow: the asked velocity is capped at this speed (m/s): catching up at a brisk walk."""


@dataclass
class RewardContext:
    """Per-step quantities every term may read; world frame, metres, [N, ...] tensors."""

    skill: torch.Tensor
    root_pos: torch.Tensor
    root_lin: torch.Tensor
    target: torch.Tensor
    """Current subtask target (carry: the destination; climb: raised climb point)."""
    obj_pos: torch.Tensor
    """The subtask's object (carry: the box)."""
    obj_rest_z: torch.Tensor
    """Resting height of the box's centre (carry)."""
    ref_xy: torch.Tensor
    """Trajectory reference point now (traj)."""
    ref_vel: torch.Tensor
    """Trajectory reference velocity now, XY m/s (traj; 0 once the path has ended)."""
    dist: torch.Tensor
    """Anchor-to-target distance of `detach.envs.success.subtask_distance`."""
    joint_power: torch.Tensor
    """sum |tau * qdot| over the hinges, W."""
    dyn_speed: torch.Tensor
    """[N, K] speeds of the dynamic objects, m/s."""


def _approach_velocity(lin: torch.Tensor, frm: torch.Tensor, to: torch.Tensor) -> torch.Tensor:
    d = to[:, :2] - frm[:, :2]
    dist = d.norm(dim=-1)
    v = (lin[:, :2] * d).sum(-1) / dist.clamp(min=1e-6)
    r = torch.exp(-1.0 * (TAR_SPEED - v).clamp(min=0.0) ** 2)
    return torch.where(dist < NEAR, torch.ones_like(r), r)


def _approach(ctx: RewardContext, goal: torch.Tensor) -> torch.Tensor:
    d = (goal[:, :2] - ctx.root_pos[:, :2]).norm(dim=-1)
    r = 0.5 * torch.exp(-0.5 * d * d) + 0.5 * _approach_velocity(ctx.root_lin, ctx.root_pos, goal)
    return torch.where(d < NEAR, torch.ones_like(r), r)


def _ref_error(ctx: RewardContext) -> torch.Tensor:
    """[N, 2] XY vector from the pelvis to the trajectory's reference point."""
    return ctx.ref_xy - ctx.root_pos[:, :2]


def traj_position(ctx: RewardContext) -> torch.Tensor:
    d2 = _ref_error(ctx).pow(2).sum(-1)
    return torch.exp(-2.0 * d2)


def traj_precision(ctx: RewardContext) -> torch.Tensor:
    """A narrow kernel exp(-20 d^2) (0.17 at the 0.3 m success threshold): exp(-2 d^2) alone
    is nearly flat there and leaves the character trailing its reference by ~0.6 m."""
    d2 = _ref_error(ctx).pow(2).sum(-1)
    return torch.exp(-20.0 * d2)


def traj_velocity(ctx: RewardContext) -> torch.Tensor:
    """Velocity tracking: the asked velocity is the reference's own plus `TRACK_GAIN` times the
    error toward it (capped at `TRACK_MAX_SPEED`); dense at any distance, and it asks the
    character to stop on the end point once the reference has stopped there."""
    want = ctx.ref_vel + TRACK_GAIN * _ref_error(ctx)
    speed = want.norm(dim=-1, keepdim=True)
    want = want * (TRACK_MAX_SPEED / speed.clamp(min=TRACK_MAX_SPEED))
    err2 = ((ctx.root_lin[:, :2] - want) ** 2).sum(-1)
    return torch.exp(-0.5 * err2)


def carry_walk_to_box(ctx: RewardContext) -> torch.Tensor:
    r = _approach(ctx, ctx.obj_pos)
    delivered = (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1) < NEAR
    return torch.where(delivered, torch.ones_like(r), r)


def carry_box_height(ctx: RewardContext) -> torch.Tensor:
    far = (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1) > NEAR
    goal = torch.where(far, ctx.obj_rest_z + 0.3, ctx.target[:, 2])
    return torch.exp(-10.0 * (ctx.obj_pos[:, 2] - goal) ** 2)


def carry_box_to_target(ctx: RewardContext) -> torch.Tensor:
    d_xy = (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1)
    d3 = (ctx.obj_pos - ctx.target).norm(dim=-1)
    return 0.5 * torch.exp(-0.5 * d_xy * d_xy) + 0.5 * torch.exp(-5.0 * d3 * d3)


def climb_approach(ctx: RewardContext) -> torch.Tensor:
    return _approach(ctx, ctx.target)


def climb_elevation(ctx: RewardContext) -> torch.Tensor:
    return torch.exp(-5.0 * ctx.dist ** 2)


def sit_approach(ctx: RewardContext) -> torch.Tensor:
    return _approach(ctx, ctx.target)


def sit_seat(ctx: RewardContext) -> torch.Tensor:
    return torch.exp(-10.0 * ctx.dist ** 2)


TERMS: dict[str, tuple[Callable[[RewardContext], torch.Tensor], float]] = {
    "traj/position": (traj_position, 0.4),
    "traj/precision": (traj_precision, 0.3),
    "traj/velocity": (traj_velocity, 0.3),
    "carry/walk_to_box": (carry_walk_to_box, 0.2),
    "carry/box_height": (carry_box_height, 0.2),
    "carry/box_to_target": (carry_box_to_target, 0.6),
    "climb/approach": (climb_approach, 0.3),
    "climb/elevation": (climb_elevation, 0.7),
    "sit/approach": (sit_approach, 0.3),
    "sit/seat": (sit_seat, 0.7),
}
"""Registered terms with their default weights (overridden by `rewards.terms`)."""


class RewardManager:
    """Weighted sum of the current skill's terms plus the penalties; per-term logging."""

    def __init__(self, cfg: RewardsCfg) -> None:
        unknown = sorted(set(cfg.terms) - set(TERMS))
        if unknown:
            raise ValueError(f"rewards.terms: unknown term '{unknown[0]}'; valid terms: {', '.join(TERMS)}")
        self.cfg = cfg
        self.weights = {name: float(cfg.terms.get(name, w)) for name, (_, w) in TERMS.items()}
        self.active = {n: w for n, w in self.weights.items() if w != 0.0}
        self.sums: dict[str, torch.Tensor] = {}

    def table(self) -> str:
        rows = [(n, f"{w:g}") for n, w in self.active.items()]
        rows += [("penalty/power", f"-{self.cfg.power_coeff:g} x W"),
                 ("penalty/dyn_obj_speed",
                  f"-{self.cfg.dyn_obj_speed_penalty_coeff:g} x (v - {self.cfg.dyn_obj_speed_threshold:g})+")]
        width = max(len(r[0]) for r in rows)
        lines = ["Active reward terms", f"  {'term':<{width}}  weight", f"  {'-' * width}  ------"]
        lines += [f"  {n:<{width}}  {w}" for n, w in rows]
        return "\n".join(lines)

    def compute(self, ctx: RewardContext) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """(reward [N], {term: value [N] where active}); terms of other skills are skipped."""
        total = torch.zeros_like(ctx.dist)
        parts: dict[str, torch.Tensor] = {}
        for name, w in self.active.items():
            skill = SKILLS.index(name.split("/")[0])
            mask = ctx.skill == skill
            if not bool(mask.any()):
                continue
            val = TERMS[name][0](ctx)
            total = total + torch.where(mask, w * val, torch.zeros_like(val))
            parts[name] = val[mask]
        power = -self.cfg.power_coeff * ctx.joint_power
        dyn = -self.cfg.dyn_obj_speed_penalty_coeff * (
            ctx.dyn_speed - self.cfg.dyn_obj_speed_threshold).clamp(min=0.0).sum(-1)
        parts["penalty/power"], parts["penalty/dyn_obj_speed"] = power, dyn
        return total + power + dyn, parts
