"""Adversarial motion prior: a discriminator between reference motion and policy motion.

The discriminator scores a window of AMP features (10 control steps) optionally conditioned on
the current skill's one-hot ("task-specific discrimination": reference windows are drawn
from that skill's clip group). Its score becomes the style reward. Objectives:
- `lsgan` (AMP, Peng et al. 2021): D(ref) -> +1, D(policy) -> -1, style reward
  max(0, 1 - 0.25 (d - 1)^2);
- `logistic` (GAIL-style): BCE with logits, style reward -log(1 - sigmoid(d)).
Both with a gradient penalty on reference samples and an L2 penalty on the output layer's
weights (logit regularisation).
"""

from __future__ import annotations

from typing import Sequence

import torch
import torch.nn as nn
import torch.nn.functional as F
from rsl_rl.modules import EmpiricalNormalization


class AmpDiscriminator(nn.Module):
    """MLP discriminator D(window, skill) -> logit, with running input normalisation."""

    def __init__(self, input_dim: int, cond_dim: int = 0, hidden: Sequence[int] = (1024, 512),
                 objective: str = "lsgan") -> None:
        super().__init__()
        if objective not in ("lsgan", "logistic"):
            raise ValueError(f"unknown AMP objective {objective!r}")
        self.objective = objective
        self.input_dim, self.cond_dim = input_dim, cond_dim
        self.normalizer = EmpiricalNormalization(input_dim)
        layers: list[nn.Module] = []
        width = input_dim + cond_dim
        for h in hidden:
            layers += [nn.Linear(width, h), nn.ReLU()]
            width = h
        self.trunk = nn.Sequential(*layers)
        self.head = nn.Linear(width, 1)
        nn.init.uniform_(self.head.weight, -1.0, 1.0)
        self.head.weight.data.mul_(0.01)
        nn.init.zeros_(self.head.bias)

    def forward(self, amp_obs: torch.Tensor, cond: torch.Tensor | None = None) -> torch.Tensor:
        """[B, input_dim] (+ [B, cond_dim]) -> logits [B]."""
        x = self.normalizer(amp_obs)
        if self.cond_dim:
            x = torch.cat([x, cond], dim=-1)
        return self.head(self.trunk(x)).squeeze(-1)

    @torch.no_grad()
    def style_reward(self, amp_obs: torch.Tensor, cond: torch.Tensor | None = None) -> torch.Tensor:
        """Style reward in [0, 1] (lsgan) or [0, inf) (logistic) per sample."""
        d = self.forward(amp_obs, cond)
        if self.objective == "lsgan":
            return torch.clamp(1.0 - 0.25 * (d - 1.0) ** 2, min=0.0)
        return -torch.log(torch.clamp(1.0 - torch.sigmoid(d), min=1e-4))

    def loss(self, ref_obs: torch.Tensor, policy_obs: torch.Tensor,
             ref_cond: torch.Tensor | None = None, policy_cond: torch.Tensor | None = None,
             grad_penalty: float = 5.0, logit_reg: float = 0.01) -> dict[str, torch.Tensor]:
        """Discriminator loss terms; `total` is what to minimise."""
        ref_obs = ref_obs.detach().requires_grad_(True)
        d_ref = self.forward(ref_obs, ref_cond)
        d_pol = self.forward(policy_obs.detach(), policy_cond)
        if self.objective == "lsgan":
            task = 0.5 * ((d_ref - 1.0) ** 2).mean() + 0.5 * ((d_pol + 1.0) ** 2).mean()
        else:
            task = 0.5 * (F.binary_cross_entropy_with_logits(d_ref, torch.ones_like(d_ref))
                          + F.binary_cross_entropy_with_logits(d_pol, torch.zeros_like(d_pol)))
        grad = torch.autograd.grad(d_ref.sum(), ref_obs, create_graph=True)[0]
        penalty = grad.pow(2).sum(dim=-1).mean()
        logit = self.head.weight.pow(2).sum()
        total = task + grad_penalty * penalty + logit_reg * logit
        with torch.no_grad():
            accuracy = 0.5 * ((d_ref > 0).float().mean() + (d_pol < 0).float().mean())
        return {"total": total, "objective": task, "grad_penalty": penalty,
                "logit_reg": logit, "accuracy": accuracy,
                "d_ref": d_ref.mean().detach(), "d_policy": d_pol.mean().detach()}


class ReplayBuffer:
    """Ring buffer of past policy AMP windows (and their skill one-hots), on one device.

    Training the discriminator on old policy samples as well as the newest rollout keeps it
    from forgetting earlier behaviour (AMP's replay buffer).
    """

    def __init__(self, capacity: int, obs_dim: int, cond_dim: int, device: str | torch.device):
        self.capacity = capacity
        self.obs = torch.zeros(capacity, obs_dim, device=device)
        self.cond = torch.zeros(capacity, max(cond_dim, 0), device=device)
        self.size = 0
        self._next = 0

    def insert(self, obs: torch.Tensor, cond: torch.Tensor | None = None) -> None:
        n = obs.shape[0]
        if n >= self.capacity:
            obs, cond = obs[-self.capacity:], None if cond is None else cond[-self.capacity:]
            n = self.capacity
        idx = (torch.arange(n, device=obs.device) + self._next) % self.capacity
        self.obs[idx] = obs
        if cond is not None and self.cond.shape[1]:
            self.cond[idx] = cond
        self._next = (self._next + n) % self.capacity
        self.size = min(self.size + n, self.capacity)

    def state_dict(self) -> dict[str, torch.Tensor | int]:
        """The filled part of the buffer and its write position: a resumed run replays the
        same old windows as the uninterrupted one would."""
        return {"obs": self.obs[:self.size].clone(), "cond": self.cond[:self.size].clone(),
                "size": self.size, "next": self._next, "capacity": self.capacity}

    def load_state_dict(self, state: dict[str, torch.Tensor | int]) -> None:
        obs, cond, size = state["obs"], state["cond"], int(state["size"])
        if int(state["capacity"]) != self.capacity or obs.shape[1:] != self.obs.shape[1:] \
                or cond.shape[1:] != self.cond.shape[1:] or not 0 <= size <= self.capacity:
            raise ValueError(f"replay buffer of capacity {state['capacity']} x {tuple(obs.shape[1:])} "
                             f"does not fit {self.capacity} x {tuple(self.obs.shape[1:])}")
        self.obs[:size] = obs.to(self.obs.device)
        self.cond[:size] = cond.to(self.cond.device)
        self.size, self._next = size, int(state["next"]) % self.capacity

    def sample(self, n: int) -> tuple[torch.Tensor, torch.Tensor]:
        if self.size == 0:
            raise RuntimeError("replay buffer is empty")
        idx = torch.randint(0, self.size, (n,), device=self.obs.device)
        return self.obs[idx], self.cond[idx]
