"""CML (Xu et al. 2023, "Composite Motion Learning with Task Control") as this platform runs it
(kind `cml`, config `configs.CMLCfg`: trunk, rsl-rl model).

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
becomes CML's frozen meta policy and a cooperative policy (`CooperativePolicy`) learns
the new skills by mixing its own action with the meta action per action dimension. See
`CMLModel`.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn as nn
from rsl_rl.modules import MLP, EmpiricalNormalization
from tensordict import TensorDict

from detach.models.configs import CMLCfg
from detach.models.layout import ObsLayout, align_time, no_columns, stack_columns
from detach.models.registry import register_model
from detach.models.structured import StructuredModel


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


class CooperativePolicy(nn.Module):
    """CML's cooperative policy (incremental learning): a CML network of its own (input
    normaliser, GRU trunk, MLP head) that outputs, per action dimension, an action and a mixing
    weight w in [0, 1]. The executed mean is (1 - w) * a_meta + w * a_coop: per body part
    (per joint), how much the new policy takes over from the frozen meta policy (CML's Fig. 1).

    Its action is written as an offset from the meta action, a_coop = a_meta + delta, so that
    zero-initialised last layers (delta = 0, w = 0.5) make the mix equal the meta action
    exactly: mix = a_meta + w * delta. This is the same family of policies as an independent
    a_coop (delta = a_coop - a_meta); only the starting point differs."""

    def __init__(self, layout: ObsLayout, cfg: CMLCfg, num_actions: int) -> None:
        super().__init__()
        self.layout = layout
        width = sum(layout.dims)
        self.obs_normalizer = EmpiricalNormalization(width) if cfg.obs_normalization else nn.Identity()
        self.trunk = CMLTrunk(layout, cfg)
        self.head = MLP(self.trunk.out_dim, 2 * num_actions, cfg.adapter_units, cfg.activation)
        last = self.head[-1]
        nn.init.zeros_(last.weight)
        nn.init.zeros_(last.bias)

    def forward(self, raw: torch.Tensor) -> tuple[torch.Tensor, torch.Tensor]:
        """raw [N, sum of group widths] (the meta policy's unnormalised input) -> (delta, w)."""
        groups = self.layout.split(self.obs_normalizer(raw))
        delta, logits = self.head(self.trunk(groups)).chunk(2, dim=-1)
        return delta, torch.sigmoid(logits)

    def mix(self, meta_action: torch.Tensor, raw: torch.Tensor) -> torch.Tensor:
        """The executed mean (1 - w) a_meta + w (a_meta + delta) = a_meta + w delta."""
        delta, weight = self(raw)
        return meta_action + weight * delta

    @torch.no_grad()
    def update_normalization(self, raw: torch.Tensor) -> None:
        if isinstance(self.obs_normalizer, EmpiricalNormalization):
            self.obs_normalizer.update(raw)


class CMLModel(StructuredModel):
    """CML (`detach.models.cml`): GRU over the observation window; with value_objectives, its
    multi-objective critic.

    Incremental learning (`incremental`, actor only; CML's meta policy + cooperative policy,
    implemented from the CML paper's description, its public code does not contain it): this
    network is the meta policy, loaded from the previous stage (`train.init_from`) and frozen
    (parameters and input normaliser); a `CooperativePolicy` (new, own normaliser, trained)
    mixes its action in per action dimension, starting with the mix equal to the meta action.
    The action std stays trainable (PPO's exploration noise; CML's is state-dependent, ours
    rsl-rl's state-independent one). The critic is not frozen: it starts from the previous
    stage's multi-objective critic and trains fully.
    """

    trunk_class = CMLTrunk
    config_class = CMLCfg
    cfg: CMLCfg

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.cooperative: CooperativePolicy | None = None
        if self.cfg.incremental and self.distribution is not None:
            meta = [p for p in self.parameters() if not any(p is q for q in self.distribution.parameters())]
            for p in meta:
                p.requires_grad_(False)
            self.cooperative = CooperativePolicy(self.layout, self.cfg, self.distribution.output_dim)

    def _raw_input(self, obs: TensorDict) -> torch.Tensor:
        return torch.cat([obs[g] for g in self.obs_groups], dim=-1)

    def head_output(self, latent: torch.Tensor, obs: TensorDict) -> torch.Tensor:
        meta = self.mlp(latent)
        return meta if self.cooperative is None else self.cooperative.mix(meta, self._raw_input(obs))

    def mixing_weights(self, obs: TensorDict) -> torch.Tensor:
        """w [N, num_actions] in [0, 1]: the cooperative policy's share of each action dimension."""
        if self.cooperative is None:
            raise ValueError("mixing_weights: this CML model is not incremental")
        return self.cooperative(self._raw_input(obs))[1]

    def update_normalization(self, obs: TensorDict) -> None:
        if self.cooperative is None:
            super().update_normalization(obs)
        else:
            self.cooperative.update_normalization(self._raw_input(obs))

    def new_parameter_prefixes(self) -> tuple[str, ...]:
        return () if self.cooperative is None else ("cooperative.",)


register_model(CMLModel, labels={"cml": "CML", "cml_incremental": "CML (incremental)"})
