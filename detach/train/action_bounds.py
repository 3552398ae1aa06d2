"""A penalty on policy action means beyond the actions' range (rl_games' `bounds_loss`, which
TokenHSI trains with at coefficient 10 and soft bound 1.1).

Why: the env clips every action to [-1, 1]. A Gaussian policy whose mean drifts far beyond
that (a puppet's pelvis-height action at 5.4, its servo pinned at the top) samples only clipped
actions, all of which do the same thing, so PPO's advantages carry no signal to bring it back:
the puppet hovered a metre above LH1's raised seat for hundreds of iterations. rsl-rl's PPO has
no such term, so it runs beside PPO's update (`AmpPPO.policy_loss_fn`).
"""

from __future__ import annotations

import torch

SOFT_BOUND = 1.1
"""Means within +-SOFT_BOUND cost nothing (rl_games' soft bound)."""


def action_bound_loss(mu: torch.Tensor, coef: float) -> tuple[torch.Tensor, dict[str, float]]:
    """(coef * mean over the batch of sum over actions of the squared excess of mu [B, A] beyond
    +-`SOFT_BOUND`, logs: the loss and the share of mean actions beyond the bound)."""
    excess = (mu - SOFT_BOUND).clamp(min=0.0) + (mu + SOFT_BOUND).clamp(max=0.0)
    loss = coef * excess.square().sum(-1).mean()
    return loss, {"action_bound/loss": float(loss.detach()),
                  "action_bound/beyond": float((excess != 0).float().mean())}
