"""The policy rsl-rl exports (`as_jit`, `as_onnx`; `detach-run export`): any model kind's actor
as one module on the flat observation, its input normaliser inside."""

from __future__ import annotations

import copy

import torch
import torch.nn as nn


class FlatPolicy(nn.Module):
    """A `StructuredModel` actor as rsl-rl exports policies: the deterministic action of the
    flat observation `obs` [N, D] (the actor's groups concatenated in `obs_groups` order, raw:
    the input normaliser is inside). A deep copy on the CPU in eval mode; `groups`, `dims` and
    `history` describe the layout of `obs` (`detach.runs.export` writes them beside the file)."""

    is_recurrent: bool = False

    def __init__(self, model: nn.Module, verbose: bool = False) -> None:
        super().__init__()
        if model.distribution is None:
            raise ValueError("FlatPolicy: export the actor, not the critic")
        for cache in ("_latent_cache", "_forward_cache"):  # a training pass's graph cannot be copied
            if cache in model.__dict__:
                setattr(model, cache, None)
        self.model = copy.deepcopy(model).cpu().eval()
        self.verbose = verbose
        self.groups = tuple(model.obs_groups)
        self.dims = tuple(model.layout.dim(g) for g in self.groups)
        self.history = {g: model.layout.history_shape(g) for g in self.groups if g in ("self", "env")}
        self.input_size = sum(self.dims)
        self.num_actions = int(model.distribution.output_dim)
        self.eval()

    def forward(self, obs: torch.Tensor) -> torch.Tensor:
        groups = dict(zip(self.groups, torch.split(obs, list(self.dims), dim=-1)))
        return self.model(groups)

    def get_dummy_inputs(self) -> tuple[torch.Tensor]:
        return (torch.zeros(2, self.input_size),)

    @property
    def input_names(self) -> list[str]:
        return ["obs"]

    @property
    def output_names(self) -> list[str]:
        return ["actions"]

    @torch.jit.unused
    def reset(self) -> None:
        """No recurrent state between calls (CML's GRU reads the window in the input)."""
