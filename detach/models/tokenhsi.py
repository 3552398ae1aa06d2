"""TokenHSI (Pan et al. 2025) as published: tokenizers, masked shared transformer, adapters
(kind `tokenhsi`, config `configs.TokenHSICfg`: trunks, head adapter, rsl-rl model).

Policy (`TokenHSITrunk`): one token per input, all in one d_model space (TokenHSI's "unified
token space", the coupling DETACH argues against):
- a proprioception tokenizer on the newest `self_frames` frames of the `self` history
  (TokenHSI's humanoid state is the current frame);
- one task tokenizer per skill of the run (`ObsSpec.one_hot_skills()`, the one-hot order),
  reading that skill's task observation: the parts of the newest env frame its
  `Skill.task_observation` names (`ObsSpec.env_fields`; e.g. follow: target, path, height
  map);
- a learnable action token.
Tokenizers are MLPs `tokenizer_units` -> d_model with the activation after every layer, the
last one included (TokenHSI's tokenizer MLPs). The transformer (`num_layers` post-norm layers,
`num_heads`, feed-forward `ff_dim` with ReLU, no dropout, no positional embedding: TokenHSI's
configuration) sees [action, self, task_1 .. task_K] with a key padding mask that hides the
task tokens of inactive skills: only the action token, the self token and the current skill's
task token are visible, so a skill's behaviour never depends on another skill's tokenizer.
The action token's output is the latent of the action head (`adapter_units`, [1024, 512]).

Value function (`TokenHSIValueTrunk`): TokenHSI's critic is a separate MLP
(`critic_units`, [2048, 1024, 512]) on the full observation; here that is the `critic` group
(the newest self and env frames, the one-hot, privileged extras). With `shared_trunk` the
critic reads the actor's transformer instead (an option of this platform, not TokenHSI's).

Adapter stage (`adapt_skills`, TokenHSI's skill adaptation, `HeadAdapter`): see `TokenHSIModel`.
"""

from __future__ import annotations

from typing import Any

import torch
import torch.nn as nn
from rsl_rl.modules import MLP, EmpiricalNormalization
from tensordict import TensorDict

from detach.config.schema import ModelCfg
from detach.models.attention import MultiHeadAttention
from detach.models.configs import TokenHSICfg
from detach.models.layout import ObsLayout, no_columns
from detach.models.registry import register_model
from detach.models.structured import StructuredModel
from detach.skills import canonical_name, skill_class

ACTIVE_SKILLS = "active_skills"
"""Key of the [N, K] bool mask of the current skill(s) in the trunk's input dict; taken from the
raw `task` one-hot (a normalised one-hot loses it when a skill was always active)."""


def task_observation_index(layout: ObsLayout, skill: str) -> torch.Tensor:
    """Indices, within one env frame, of the parts the skill's task observation is made of."""
    fields = layout.spec.env_fields()
    frame = range(layout.spec.env_dim)
    return torch.tensor([i for part in skill_class(skill).task_observation for i in frame[fields[part]]],
                        dtype=torch.long)


class TokenEncoder(nn.Module):
    """TokenHSI's transformer: post-norm layers x = LN(x + MHA(x)), x = LN(x + FF(x)), ReLU
    feed-forward, no dropout and no final norm; `visible` [N, L] is the key padding mask."""

    def __init__(self, dim: int, heads: int, ff_dim: int, layers: int) -> None:
        super().__init__()
        self.attention = nn.ModuleList(
            MultiHeadAttention(dim, heads, what="model.num_heads vs model.d_model") for _ in range(layers))
        self.feed_forward = nn.ModuleList(
            nn.Sequential(nn.Linear(dim, ff_dim), nn.ReLU(), nn.Linear(ff_dim, dim)) for _ in range(layers))
        self.attention_norms = nn.ModuleList(nn.LayerNorm(dim) for _ in range(layers))
        self.feed_forward_norms = nn.ModuleList(nn.LayerNorm(dim) for _ in range(layers))

    def forward(self, x: torch.Tensor, visible: torch.Tensor) -> torch.Tensor:
        for attend, feed, norm_a, norm_f in zip(self.attention, self.feed_forward, self.attention_norms,
                                                self.feed_forward_norms):
            x = norm_a(x + attend(x, visible=visible))
            x = norm_f(x + feed(x))
        return x


class TokenHSITrunk(nn.Module):
    """Named groups (+ `ACTIVE_SKILLS`) -> the action token's output [N, d_model]."""

    def __init__(self, layout: ObsLayout, cfg: TokenHSICfg) -> None:
        super().__init__()
        layout.require("self", "env", "task")
        self.layout = layout
        skills = layout.spec.one_hot_skills()
        if layout.spec.num_skills != len(skills):
            raise ValueError(f"TokenHSI has one task tokenizer per skill of the run ({', '.join(skills)}); "
                             f"the observation's task one-hot has {layout.spec.num_skills} entries")
        steps, self_dim = layout.history_shape("self")
        self.self_frames = steps if cfg.self_frames == 0 else min(cfg.self_frames, steps)
        d, units, act = cfg.d_model, cfg.tokenizer_units, cfg.activation
        self.self_tokenizer = MLP(self.self_frames * self_dim, d, units, act, last_activation=act)
        self.task_tokenizers = nn.ModuleDict()
        for skill in skills:
            index = task_observation_index(layout, skill)
            self.register_buffer(f"{skill}_index", index, persistent=False)
            self.task_tokenizers[skill] = MLP(index.numel(), d, units, act, last_activation=act)
        self.action_token = nn.Parameter(nn.init.trunc_normal_(torch.zeros(1, 1, d), std=0.02))
        self.transformer = TokenEncoder(d, cfg.num_heads, cfg.ff_dim, cfg.num_layers)
        self.out_dim = d

    def input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """The first layers of the self tokenizer (the newest `self_frames`, flattened) and of
        each task tokenizer (its entries of the newest env frame)."""
        lay = self.layout
        own = lay.columns("self")[:, -self.self_frames:].T.reshape(-1, 1)
        newest_env = lay.columns("env")[:, -1:]
        out = [(self.self_tokenizer[0].weight, own)]
        for skill, tokenizer in self.task_tokenizers.items():
            out.append((tokenizer[0].weight, newest_env[getattr(self, f"{skill}_index").cpu()]))
        return out

    def output_columns(self) -> torch.Tensor:
        return no_columns(self.out_dim)

    @torch.no_grad()
    def copy_task_tokenizer(self, skill: str, source: str, mean: torch.Tensor, scale: torch.Tensor) -> None:
        """Make `skill`'s task tokenizer the trained one of `source` (`TokenHSICfg.tokenizer_from`):
        the parts of the env frame both read keep `source`'s first-layer columns, the parts only
        `skill` reads start at zero, and `source`'s path columns fold into the target's XY
        columns: outside path-following subtasks every path point is the target's XY
        (`detach.envs.observations.env_frame`), so on such a frame `skill`'s token equals the
        token `source` would give it. `mean` and `scale` [env_dim] are the normaliser's mean and
        std + eps of the newest env frame's inputs (the tokenizers read (x - mean) / scale)."""
        fields = self.layout.spec.env_fields()
        src, dst = (getattr(self, f"{canonical_name(s)}_index").tolist() for s in (source, skill))
        src_tok, dst_tok = self.task_tokenizers[canonical_name(source)], self.task_tokenizers[canonical_name(skill)]
        w_src, b_src = src_tok[0].weight, src_tok[0].bias
        weight, bias = torch.zeros_like(dst_tok[0].weight), b_src.clone()
        at = {i: c for c, i in enumerate(dst)}
        target = range(self.layout.spec.env_dim)[fields["target"]]
        path = set(range(self.layout.spec.env_dim)[fields["path"]])
        for c, i in enumerate(src):
            if i in at:
                weight[:, at[i]] += w_src[:, c]
            elif i in path and target[0] in at:  # a path point's x or y reads the target's
                t = target[(i - fields["path"].start) % 2]
                weight[:, at[t]] += w_src[:, c] * (scale[t] / scale[i])
                bias += w_src[:, c] * ((mean[t] - mean[i]) / scale[i])
        dst_tok[0].weight.copy_(weight)
        dst_tok[0].bias.copy_(bias)
        for d, s in zip(list(dst_tok)[1:], list(src_tok)[1:]):
            d.load_state_dict(s.state_dict())

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        if ACTIVE_SKILLS not in groups:
            raise ValueError(f"TokenHSITrunk needs groups['{ACTIVE_SKILLS}'] (the raw one-hot > 0.5)")
        own = groups["self"]
        n = own.shape[0]
        newest_env = groups["env"][:, -1]
        tokens = [self.action_token.expand(n, -1, -1),
                  self.self_tokenizer(own[:, -self.self_frames:].reshape(n, -1)).unsqueeze(1)]
        for skill, tokenizer in self.task_tokenizers.items():
            index = getattr(self, f"{skill}_index")
            tokens.append(tokenizer(newest_env.index_select(-1, index)).unsqueeze(1))
        always = torch.ones(n, 2, dtype=torch.bool, device=own.device)
        visible = torch.cat([always, groups[ACTIVE_SKILLS]], dim=1)
        return self.transformer(torch.cat(tokens, dim=1), visible)[:, 0]


class TokenHSIValueTrunk(nn.Module):
    """The critic's input: the `critic` group (the full newest observation) as it is."""

    def __init__(self, layout: ObsLayout, cfg: TokenHSICfg) -> None:
        super().__init__()
        layout.require("critic")
        self.layout = layout
        self.out_dim = layout.dim("critic")

    def input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        return []

    def output_columns(self) -> torch.Tensor:
        """The `critic` group, passed on."""
        return self.layout.columns("critic")

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        return groups["critic"]


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


class TokenHSIModel(StructuredModel):
    """TokenHSI: tokenizers, masked transformer, action-token head;
    as a critic, a separate MLP on the `critic` group (`critic_units`).

    Adapter stage (`adapt_skills`, actor only): TokenHSI's way of learning skills after the
    base is trained. Frozen (requires_grad False, never stepped): the proprioception tokenizer,
    the task tokenizers of the other skills, the action token, the transformer, the action head
    and the input normaliser (its statistics stay those of the previous stage, and the adapted
    skills' tokenizers read through it too). Trained: the adapted skills' task tokenizers,
    the `HeadAdapter` (new, zero-initialised: the first actions are the base policy's) and the
    action std (PPO's exploration noise; TokenHSI keeps it constant in both stages). The
    critic is not frozen: it starts from the previous stage's critic (same input, same shape)
    and trains fully, where TokenHSI's adapter stage builds a fresh critic; the critic only
    shapes the advantages, and a warm start keeps `train.init_from` a plain load.
    """

    trunk_class = TokenHSITrunk
    config_class = TokenHSICfg
    cfg: TokenHSICfg

    def __init__(self, *args: Any, **kwargs: Any) -> None:
        super().__init__(*args, **kwargs)
        self.adapter: HeadAdapter | None = None
        if self.cfg.adapt_skills and self.distribution is not None:
            self.adapter = HeadAdapter(self.mlp)
            adapted = [self.trunk.task_tokenizers[canonical_name(s)] for s in self.cfg.adapt_skills]
            trained = {id(p) for m in (*adapted, self.adapter, self.distribution) for p in m.parameters()}
            for p in self.parameters():
                if id(p) not in trained:
                    p.requires_grad_(False)

    @classmethod
    def make_trunk(cls, layout: ObsLayout, cfg: ModelCfg, value_only: bool) -> nn.Module:
        return TokenHSIValueTrunk(layout, cfg) if value_only else TokenHSITrunk(layout, cfg)

    @classmethod
    def head_units(cls, cfg: ModelCfg, value_only: bool) -> tuple[int, ...]:
        return tuple(cfg.critic_units if value_only else cfg.adapter_units)

    def normalized_groups(self, obs: TensorDict) -> dict[str, torch.Tensor]:
        groups = super().normalized_groups(obs)
        if "task" in self.layout.groups:
            groups[ACTIVE_SKILLS] = obs["task"] > 0.5
        return groups

    def head_output(self, latent: torch.Tensor, obs: TensorDict) -> torch.Tensor:
        return self.mlp(latent) if self.adapter is None else self.adapter(self.mlp, latent)

    def update_normalization(self, obs: TensorDict) -> None:
        if self.adapter is None:
            super().update_normalization(obs)

    def new_parameter_prefixes(self) -> tuple[str, ...]:
        return () if self.adapter is None else ("adapter.",)

    def start_from_loaded(self) -> list[str]:
        """After `train.init_from` loaded the source's weights and observation statistics (before
        they are merged): `tokenizer_from`'s copies, for each skill whose one-hot entry the
        source's statistics never saw set (mean 0: the source never ran it, so its tokenizer
        never trained). Returns "skill <- source" for each copy made."""
        norm = self.obs_normalizer
        if not self.cfg.tokenizer_from or not isinstance(norm, EmpiricalNormalization) \
                or self.distribution is None:
            return []
        mean, scale = norm._mean.reshape(-1), norm._std.reshape(-1) + norm.eps
        env = self.layout.columns("env")[:, -1]
        task = self.layout.columns("task")[:, 0]
        done = []
        for skill, source in self.cfg.tokenizer_from.items():
            if float(mean[task[self.layout.spec.one_hot_skills().index(canonical_name(skill))]]) > 0.0:
                continue  # the source ran it: its own tokenizer is trained
            self.trunk.copy_task_tokenizer(skill, source, mean[env], scale[env])
            done.append(f"{canonical_name(skill)} <- {canonical_name(source)}")
        return done


register_model(TokenHSIModel, labels={"tokenhsi": "TokenHSI", "tokenhsi_adapt": "TokenHSI (adapters)"})
