"""CML (Xu et al. 2023, "Composite Motion Learning with Task Control") as this platform runs it.

Network: a GRU encodes the observation history; its last hidden state, the task one-hot and any
extra flat group (the privileged `critic` group) form the latent of the MLP head ([1024, 512],
CML's actor and critic MLPs). The GRU runs over the T self steps, each step's input being
[self frame; env frame] (the env history resampled to T steps when its length differs). It
only spans the observation window, so the model is not recurrent for rsl-rl
(`is_recurrent = False`, no hidden state carried across env steps).

Multi-objective learning: the critic has one value head per reward objective
(`critic_objectives`: task and one per body-part discriminator, `train.amp.body_parts`), GAE
runs per objective and advantages are normalised per objective before their weighted sum
(`train.per_objective_advantage_norm`; `detach.train.amp_ppo.AmpPPO`).

Incremental learning (`incremental`): the policy of the previous stage (`train.init_from`)
becomes CML's frozen meta policy and a cooperative policy (`detach.models.adapters`) learns
the new skills by mixing its own action with the meta action per action dimension. See
`CMLModel` in `rsl_rl_models`.
"""

from __future__ import annotations

import torch
import torch.nn as nn

from dataclasses import dataclass

from detach.models.layout import ObsLayout, TrunkModelCfg, align_time, no_columns, stack_columns


@dataclass(frozen=True)
class CMLCfg(TrunkModelCfg):
    """The CML baseline (kind `cml`)."""

    kind: str = "cml"
    gru_hidden: int = 256
    incremental: bool = False
    """The policy is a frozen meta policy (this network, weights from `train.init_from`) plus a
    trainable cooperative policy that mixes its action in per action dimension."""

    def builds_on(self) -> str | None:
        return "incremental" if self.incremental else None

    def invalid(self) -> tuple[str, str] | None:
        if self.incremental and self.shared_trunk:
            return "incremental", "the meta policy is frozen; a critic cannot share its trunk (shared_trunk)"
        return None


class CMLTrunk(nn.Module):
    """Named groups -> [h_T (gru_hidden); task; extras] [N, out_dim]."""

    def __init__(self, layout: ObsLayout, cfg: CMLCfg) -> None:
        super().__init__()
        layout.require("self", "env", "task")
        self.layout = layout
        t_self, d_self = layout.history_shape("self")
        _, d_env = layout.history_shape("env")
        self.gru = nn.GRU(d_self + d_env, cfg.gru_hidden, batch_first=True)
        self.out_dim = cfg.gru_hidden + layout.dim("task") + sum(layout.dim(g) for g in layout.extra_groups)

    def input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The GRU's input weights over [self frame; env frame] (env frames resampled to the
        self history's length, so an env column stands for all of its frames)."""
        lay = self.layout
        return [(self.gru.weight_ih_l0, stack_columns(lay.columns("self"), lay.columns("env")))]

    def output_columns(self) -> torch.Tensor:
        """h_T is computed; the task one-hot and the extras are inputs passed on."""
        lay = self.layout
        return stack_columns(no_columns(self.gru.hidden_size), lay.columns("task"),
                             *(lay.columns(g) for g in lay.extra_groups))

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        x_self = groups["self"]
        x_env = align_time(groups["env"], x_self.shape[1])
        _, h = self.gru(torch.cat([x_self, x_env], dim=-1))
        parts = [h[-1], groups["task"]] + [groups[g] for g in self.layout.extra_groups]
        return torch.cat(parts, dim=-1)
