"""MLP baseline trunk: the normalised groups, flattened and concatenated (rsl-rl's MLPModel input).

The head MLP ([1024, 512] via `adapter_units`) does all the work; this trunk exists so the
baseline shares the group handling and the multi-head critic of the other kinds.
"""

from __future__ import annotations

import torch
import torch.nn as nn

from detach.config_schema import ModelCfg
from detach.models.layout import ObsLayout


class FlatTrunk(nn.Module):
    """Named groups -> [N, sum of group widths] in the obs set's group order."""

    def __init__(self, layout: ObsLayout, cfg: ModelCfg | None = None) -> None:
        super().__init__()
        self.layout = layout
        self.out_dim = sum(layout.dims)

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        n = groups[self.layout.groups[0]].shape[0]
        return torch.cat([groups[g].reshape(n, -1) for g in self.layout.groups], dim=-1)
