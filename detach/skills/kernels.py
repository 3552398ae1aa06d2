"""Reward kernels several skills share (TokenHSI/AMP-style exp kernels, each in [0, 1])."""

from __future__ import annotations

import torch

from detach.skills.context import SkillContext

TAR_SPEED = 1.5
"""Desired approach speed (m/s) of the velocity terms."""
NEAR = 0.5
"""Within this XY distance (m) of its goal an approach term pays its maximum."""


def approach_velocity(lin: torch.Tensor, frm: torch.Tensor, to: torch.Tensor) -> torch.Tensor:
    """exp(-(TAR_SPEED - v)+^2) of the velocity v (m/s) from `frm` toward `to` (XY); 1 when near."""
    d = to[:, :2] - frm[:, :2]
    dist = d.norm(dim=-1)
    v = (lin[:, :2] * d).sum(-1) / dist.clamp(min=1e-6)
    r = torch.exp(-1.0 * (TAR_SPEED - v).clamp(min=0.0) ** 2)
    return torch.where(dist < NEAR, torch.ones_like(r), r)


def approach(ctx: SkillContext, goal: torch.Tensor) -> torch.Tensor:
    """Walk the pelvis to goal [N, 3] (XY): half position kernel, half approach velocity."""
    root = ctx.state.root_pos
    d = (goal[:, :2] - root[:, :2]).norm(dim=-1)
    r = 0.5 * torch.exp(-0.5 * d * d) + 0.5 * approach_velocity(ctx.state.body_lin[:, 0], root, goal)
    return torch.where(d < NEAR, torch.ones_like(r), r)


def uniform_draw(n: int, lo: float, hi: float, gen: torch.Generator, device: torch.device) -> torch.Tensor:
    """[n] uniform in [lo, hi) from gen (on its own device), on device: mid-task starts' draws."""
    return lo + (hi - lo) * torch.rand(n, generator=gen, device=gen.device).to(device)
