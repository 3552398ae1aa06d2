"""Multi-strategy adaptive fusion (paper, Methods: "Multi-Strategy Adaptive Fusion Mechanism").

Inputs are token sequences in d_model: f_self [N, T, d] (one token per self-history step) and
f_env [N, T_env, d]. Cross-attention lets each self token query the whole env sequence (with a
single env vector the softmax over one key would be constant, so sequences are what make the
attention meaningful). Gated and MoE fusion work per token on [f_env; f_self], with f_env
resampled to the T self steps (`layout.align_time`, identity when T_env == T).
f_fused = α·f_cross + β·f_gate + γ·f_moe with learnable scalars α, β, γ (initialised to 1/3).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn
from rsl_rl.modules import MLP

from detach.models.attention import MultiHeadAttention
from detach.models.configs import FusionCfg
from detach.models.layout import align_time


class CrossAttentionFusion(nn.Module):
    """f_cross = MultiHead(Q=f_self, K=V=f_env): [N, T, d], [N, T_env, d] -> [N, T, d]."""

    def __init__(self, d_model: int, heads: int) -> None:
        super().__init__()
        self.attn = MultiHeadAttention(
            d_model, heads, cross=True, what="model.fusion.cross_attn_heads vs model.d_model"
        )

    def forward(self, f_self: torch.Tensor, f_env: torch.Tensor) -> torch.Tensor:
        return self.attn(f_self, f_env)


class GatedFusion(nn.Module):
    """f_gate = g ⊙ f_env + (1 - g) ⊙ f_self, g = σ(MLP([f_env; f_self])) with decreasing widths."""

    def __init__(self, d_model: int, hidden: tuple[int, ...], activation: str = "elu") -> None:
        super().__init__()
        self.gate = MLP(2 * d_model, d_model, hidden, activation)

    def forward(self, f_env: torch.Tensor, f_self: torch.Tensor) -> torch.Tensor:
        g = torch.sigmoid(self.gate(torch.cat([f_env, f_self], dim=-1)))
        return g * f_env + (1.0 - g) * f_self


class MoEFusion(nn.Module):
    """f_moe = Σ_i w_i E_i([f_env; f_self]), w = softmax(W_r [f_env; f_self] + b_r) (dense routing)."""

    def __init__(self, d_model: int, num_experts: int, hidden: tuple[int, ...], activation: str = "elu") -> None:
        super().__init__()
        self.router = nn.Linear(2 * d_model, num_experts)
        self.experts = nn.ModuleList(MLP(2 * d_model, d_model, hidden, activation) for _ in range(num_experts))

    def route(self, x: torch.Tensor) -> torch.Tensor:
        """Router weights [..., num_experts]; they sum to 1 over the last axis."""
        return torch.softmax(self.router(x), dim=-1)

    def forward(self, f_env: torch.Tensor, f_self: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        x = torch.cat([f_env, f_self], dim=-1)
        w = self.route(x)
        outs = torch.stack([e(x) for e in self.experts], dim=-1)  # [..., d, E]
        return (outs * w.unsqueeze(-2)).sum(-1), w


@dataclass
class FusionOutput:
    """Every intermediate the fusion losses need (all [N, T, d] except `router` [N, T, E])."""

    fused: torch.Tensor
    cross: torch.Tensor
    gate: torch.Tensor
    moe: torch.Tensor
    router: torch.Tensor
    env_aligned: torch.Tensor


class AdaptiveFusion(nn.Module):
    """The three strategies and their learnable combination α, β, γ."""

    def __init__(self, d_model: int, cfg: FusionCfg, activation: str = "elu") -> None:
        super().__init__()
        self.cross = CrossAttentionFusion(d_model, cfg.cross_attn_heads)
        self.gated = GatedFusion(d_model, cfg.gate_hidden, activation)
        self.moe = MoEFusion(d_model, cfg.num_experts, cfg.expert_hidden, activation)
        self.alpha = nn.Parameter(torch.tensor(1.0 / 3.0))
        self.beta = nn.Parameter(torch.tensor(1.0 / 3.0))
        self.gamma = nn.Parameter(torch.tensor(1.0 / 3.0))

    def forward(self, f_env: torch.Tensor, f_self: torch.Tensor) -> FusionOutput:
        env_aligned = align_time(f_env, f_self.shape[1])
        f_cross = self.cross(f_self, f_env)
        f_gate = self.gated(env_aligned, f_self)
        f_moe, w = self.moe(env_aligned, f_self)
        fused = self.alpha * f_cross + self.beta * f_gate + self.gamma * f_moe
        return FusionOutput(fused, f_cross, f_gate, f_moe, w, env_aligned)
