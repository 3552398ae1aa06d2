"""The MLP baseline (kind `mlp`, config `configs.MLPCfg`): its trunk (the normalised groups,
flattened and concatenated, rsl-rl's MLPModel input) and its rsl-rl model.

The head MLP ([1024, 512] via `adapter_units`) does all the work; this trunk exists so the
baseline shares the group handling and the multi-head critic of the other kinds. With
`model.history_frames = k > 0` it keeps only the newest k frames of each history group: the
first layer then sees k/T of the input, which matters for a flat MLP (measured in
benchmarks/RESULTS.md: 5 frames -> 1 frame, 3.3 -> 1.97 s per PPO iteration on the puppet).
"""

from __future__ import annotations

import torch
import torch.nn as nn

from detach.models.configs import MLPCfg
from detach.models.layout import HISTORY_GROUPS, ObsLayout
from detach.models.registry import register_model
from detach.models.structured import StructuredModel


class FlatTrunk(nn.Module):
    """Named groups -> [N, sum of group widths] in the obs set's group order."""

    def __init__(self, layout: ObsLayout, cfg: MLPCfg | None = None) -> None:
        super().__init__()
        self.layout = layout
        self.frames = cfg.history_frames if cfg is not None else 0
        if self.frames < 0:
            raise ValueError(f"model.history_frames must be >= 0 (0 = every frame), got {self.frames}")
        self.out_dim = sum(self._kept_width(g, w) for g, w in zip(layout.groups, layout.dims))

    @property
    def slices_history(self) -> bool:
        """True when the trunk drops frames (its input is then not the plain concatenation)."""
        return self.out_dim != sum(self.layout.dims)

    def _kept_width(self, group: str, width: int) -> int:
        if group not in HISTORY_GROUPS or self.frames == 0:
            return width
        steps, dim = self.layout.history_shape(group)
        return min(self.frames, steps) * dim

    def input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """None: the trunk passes its inputs on (`output_columns`)."""
        return []

    def output_columns(self) -> torch.Tensor:
        """[out_dim, 1]: the input column behind each output (the kept frames, concatenated)."""
        parts = []
        for g in self.layout.groups:
            cols = self.layout.columns(g)
            if g in HISTORY_GROUPS and self.frames > 0:
                cols = cols[:, -self.frames:]
            parts.append(cols.T.reshape(-1, 1))  # time-major, as forward flattens
        return torch.cat(parts)

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        n = groups[self.layout.groups[0]].shape[0]
        parts = []
        for g in self.layout.groups:
            x = groups[g]
            if g in HISTORY_GROUPS and self.frames > 0:
                x = x[:, -self.frames:]  # time-major: the newest frames are last
            parts.append(x.reshape(n, -1))
        return torch.cat(parts, dim=-1)


class MLPBaselineModel(StructuredModel):
    """Plain MLP on the concatenated normalised groups (same as rsl-rl's MLPModel)."""

    trunk_class = FlatTrunk
    config_class = MLPCfg


register_model(MLPBaselineModel, labels={"mlp": "MLP"})
