"""Policy actions -> hinge PD targets, shared by every character.

Hinge actions (the first 32 values) are PD targets: q* = clip(q_default + a * (hi - lo) / 2,
lo, hi), radians, with a nominally in [-1, 1] and q_default = 0 (standing upright, arms down).
Centring on the standing pose rather than the middle of each range (as AMP does) makes a zero
action a stable stance, which helps both exploration and scripted control; the half-range
scale still reaches every limit. A character's extra actions (the puppet's root servos) are
mapped by the character itself.
"""

from __future__ import annotations

import torch


def pd_targets(actions: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor,
               default: torch.Tensor | None = None) -> torch.Tensor:
    """[N, 32] PD targets (rad) from actions [N, >=32] and hinge ranges lo, hi [32]."""
    a = actions[:, : lo.shape[0]].clamp(-1.0, 1.0)
    q0 = torch.zeros_like(lo) if default is None else default
    return torch.maximum(torch.minimum(q0 + a * 0.5 * (hi - lo), hi), lo)


def pd_actions(targets: torch.Tensor, lo: torch.Tensor, hi: torch.Tensor,
               default: torch.Tensor | None = None) -> torch.Tensor:
    """Inverse of `pd_targets` for targets inside the ranges (scripted controllers)."""
    q0 = torch.zeros_like(lo) if default is None else default
    return ((targets - q0) / (0.5 * (hi - lo))).clamp(-1.0, 1.0)
