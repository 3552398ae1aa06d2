"""TokenHSI-style baseline trunk: one tokenizer per observation group, a unified token space.

Each group becomes one d_model token through its own MLP tokenizer (`tokenizer_units`, e.g.
[256, 128] -> 64): proprioception (the flattened self history), the task one-hot, the
non-height-map env features (target and object features of every env frame), the height maps
of every env frame, and any extra flat group (the privileged `critic` group). A learnable
action token is appended; after the transformer (num_layers, num_heads, ff_dim: TokenHSI uses
4 layers, 2 heads, FF 512 at d_model 64) the action token's output is the latent for the MLP
head. All groups share one feature space, the coupling DETACH argues against.
"""

from __future__ import annotations

import torch
import torch.nn as nn
from rsl_rl.modules import MLP

from dataclasses import dataclass

from detach.models.attention import TransformerEncoder
from detach.models.layout import ObsLayout, TrunkModelCfg


@dataclass(frozen=True)
class TokenHSICfg(TrunkModelCfg):
    """The TokenHSI baseline (kind `tokenhsi`)."""

    kind: str = "tokenhsi"
    d_model: int = 64
    num_layers: int = 4
    num_heads: int = 8
    ff_dim: int = 256
    tokenizer_units: tuple[int, ...] = (256, 128)


class TokenHSITrunk(nn.Module):
    """Named groups -> action-token feature [N, d_model]."""

    def __init__(self, layout: ObsLayout, cfg: TokenHSICfg) -> None:
        super().__init__()
        layout.require("self", "env", "task")
        self.layout = layout
        t_env, d_env = layout.history_shape("env")
        self.cells = layout.spec.height_map_cells
        d, units, act = cfg.d_model, cfg.tokenizer_units, cfg.activation
        widths = {
            "self": layout.dim("self"),
            "task": layout.dim("task"),
            "env_features": t_env * (d_env - self.cells),
            "height_map": t_env * self.cells,
        }
        widths.update({g: layout.dim(g) for g in layout.extra_groups})
        self.tokenizers = nn.ModuleDict(
            {name: MLP(w, d, units, act) for name, w in widths.items() if w > 0}
        )
        self.action_token = nn.Parameter(0.02 * torch.randn(1, 1, d))
        self.pos = nn.Parameter(0.02 * torch.randn(1, len(self.tokenizers) + 1, d))
        self.transformer = TransformerEncoder(d, cfg.num_heads, cfg.ff_dim, cfg.num_layers)
        self.out_dim = d

    def group_inputs(self, groups: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """Flat input of each tokenizer; the env history is split into features and height maps."""
        env = groups["env"]
        n = env.shape[0]
        split = env.shape[-1] - self.cells
        inputs = {
            "self": groups["self"].reshape(n, -1),
            "task": groups["task"],
            "env_features": env[..., :split].reshape(n, -1),
            "height_map": env[..., split:].reshape(n, -1),
        }
        inputs.update({g: groups[g] for g in self.layout.extra_groups})
        return inputs

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        inputs = self.group_inputs(groups)
        tokens = [tok(inputs[name]).unsqueeze(1) for name, tok in self.tokenizers.items()]
        n = tokens[0].shape[0]
        tokens.append(self.action_token.expand(n, -1, -1))
        h = self.transformer(torch.cat(tokens, dim=1) + self.pos)
        return h[:, -1]
