"""What a later training stage adds to a frozen, pre-trained policy (the baselines' way of
learning new skills): TokenHSI's head adapter and CML's cooperative policy.

Both start as the identity on the pre-trained policy: the adapted policy's first actions are
exactly the previous stage's (zero-initialised last layers), so the new stage starts from what
phase A learned and PPO moves away from it only as far as the new skills' rewards ask.
"""

from __future__ import annotations

import torch
import torch.nn as nn
from rsl_rl.modules import MLP, EmpiricalNormalization

from detach.models.cml import CMLCfg, CMLTrunk
from detach.models.layout import ObsLayout


class HeadAdapter(nn.Module):
    """TokenHSI's adapter ("internal adaptation", its published adapter configuration): beside
    every hidden linear layer of the frozen action head a trainable linear layer of the same
    shape reads the same input and adds its output before the activation. The widths are the
    head's (TokenHSI and the DETACH appendix: "Adapter Units [1024, 512]"). Every adapter
    weight and bias starts at zero, so the adapted head equals the frozen head at the start,
    while the gradient of each adapter layer (input x output-gradient) is not zero."""

    def __init__(self, head: MLP) -> None:
        super().__init__()
        hidden = [m for m in head if isinstance(m, nn.Linear)][:-1]
        self.branches = nn.ModuleList(nn.Linear(m.in_features, m.out_features) for m in hidden)
        for branch in self.branches:
            nn.init.zeros_(branch.weight)
            nn.init.zeros_(branch.bias)

    def forward(self, head: MLP, x: torch.Tensor) -> torch.Tensor:
        """The head's output on latent x [N, in] with the adapter branches added."""
        layers = list(head)
        branch = iter(self.branches)
        for layer in layers[:-1]:
            x = layer(x) + next(branch)(x) if isinstance(layer, nn.Linear) else layer(x)
        return layers[-1](x)


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
