"""Lean attention blocks on `scaled_dot_product_attention`, batch-first.

Written out (instead of nn.MultiheadAttention / nn.TransformerEncoder) because the sequences
here are short (5-8 tokens) and the batch large (4096+): the stock modules' layout copies
(time-major transposes, per-head chunking) cost more than the attention itself on CPU.
"""

from __future__ import annotations

import torch
import torch.nn as nn
import torch.nn.functional as F
from rsl_rl.utils import resolve_nn_activation


class MultiHeadAttention(nn.Module):
    """softmax(QK^T/√d_h)V over heads: query [N, Lq, dim], context [N, Lk, kv_dim] -> [N, Lq, dim].

    Self-attention (no context) uses one fused QKV projection; cross-attention projects the
    query and the context separately.
    """

    def __init__(self, dim: int, heads: int, kv_dim: int | None = None, cross: bool = False,
                 what: str = "attention") -> None:
        super().__init__()
        if dim % heads:
            raise ValueError(f"{what}: {heads} heads do not divide the width {dim}")
        self.heads = heads
        self.cross = cross
        if cross:
            self.q = nn.Linear(dim, dim)
            self.kv = nn.Linear(kv_dim or dim, 2 * dim)
        else:
            self.qkv = nn.Linear(dim, 3 * dim)
        self.out = nn.Linear(dim, dim)

    def forward(self, x: torch.Tensor, context: torch.Tensor | None = None,
                visible: torch.Tensor | None = None) -> torch.Tensor:
        """`visible` [N, Lk] bool (optional): the keys each sample may attend to (a key padding
        mask with True = attend, e.g. TokenHSI's hiding of inactive task tokens)."""
        n, lq, dim = x.shape
        h = self.heads
        if self.cross:
            if context is None:
                raise ValueError("cross-attention needs a context")
            q = self.q(x).view(n, lq, h, dim // h).transpose(1, 2)
            k, v = self.kv(context).view(n, context.shape[1], 2, h, dim // h).permute(2, 0, 3, 1, 4).unbind(0)
        else:
            q, k, v = self.qkv(x).view(n, lq, 3, h, dim // h).permute(2, 0, 3, 1, 4).unbind(0)
        mask = None if visible is None else visible[:, None, None, :]
        a = F.scaled_dot_product_attention(q, k, v, attn_mask=mask)
        return self.out(a.transpose(1, 2).reshape(n, lq, dim))


class TransformerBlock(nn.Module):
    """Pre-norm block: x + MHA(LN(x)), then x + FF(LN(x)). No dropout (PPO needs a stable policy)."""

    def __init__(self, dim: int, heads: int, ff_dim: int, activation: str = "relu") -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(dim)
        self.attn = MultiHeadAttention(dim, heads, what="model.num_heads vs model.d_model")
        self.norm2 = nn.LayerNorm(dim)
        self.ff = nn.Sequential(nn.Linear(dim, ff_dim), resolve_nn_activation(activation), nn.Linear(ff_dim, dim))

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x))
        return x + self.ff(self.norm2(x))


class TransformerEncoder(nn.Module):
    """`layers` pre-norm blocks + final LayerNorm: [N, L, dim] -> [N, L, dim]."""

    def __init__(self, dim: int, heads: int, ff_dim: int, layers: int, activation: str = "relu") -> None:
        super().__init__()
        self.blocks = nn.ModuleList(TransformerBlock(dim, heads, ff_dim, activation) for _ in range(layers))
        self.norm = nn.LayerNorm(dim)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        for block in self.blocks:
            x = block(x)
        return self.norm(x)
