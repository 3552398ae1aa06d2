"""The model module of `07_add_model.py`: a model kind is this one file (config class, trunk,
rsl-rl model, `register_model`) plus a model YAML (`linear.yaml`) whose
`kind: linear_model:LinearCfg` imports it. Here `linear`: one linear layer with tanh over the
newest frame of each observation group, then the usual head MLP."""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn as nn

from detach.config.schema import ModelCfg
from detach.models import StructuredModel, register_model
from detach.models.layout import HISTORY_GROUPS, ObsLayout


@dataclass(frozen=True)
class LinearCfg(ModelCfg):
    """Every `model.*` key of the YAML: ModelCfg's (adapter_units, activation, ...) and these."""

    kind: str = "linear"
    width: int = 64
    """Outputs of the linear layer (the head MLP's input)."""


class LinearTrunk(nn.Module):
    """Named, normalised groups ([N, T, d] histories, [N, D] flat) -> [N, out_dim]."""

    def __init__(self, layout: ObsLayout, cfg: LinearCfg) -> None:
        super().__init__()
        self.layout = layout
        self.columns = torch.cat([layout.columns(g)[:, -1:] for g in layout.groups])
        self.linear = nn.Linear(len(self.columns), cfg.width)
        self.out_dim = cfg.width

    def input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The layers that read the input, with the input column of each weight column."""
        return [(self.linear.weight, self.columns)]

    def output_columns(self) -> torch.Tensor:
        """No output is an input passed on (-1)."""
        return torch.full((self.out_dim, 1), -1)

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        newest = [groups[g][:, -1] if g in HISTORY_GROUPS else groups[g] for g in self.layout.groups]
        return torch.tanh(self.linear(torch.cat(newest, dim=-1)))


class LinearModel(StructuredModel):
    trunk_class = LinearTrunk
    config_class = LinearCfg


register_model(LinearModel, labels={"linear": "Linear"})
