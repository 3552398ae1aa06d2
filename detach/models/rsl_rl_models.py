"""The four kinds of network as rsl-rl-lib actor/critic models.

rsl-rl 5.x builds actor and critic as `cls(obs, obs_groups, obs_set, output_dim, **cfg)` and
calls only the `MLPModel` API (forward with `stochastic_output`, `get_output_log_prob`,
`output_distribution_params`, `output_entropy`, `get_kl_divergence`, `update_normalization`,
`reset`, `get_hidden_state`). Each class here is an `MLPModel` whose `get_latent` runs a trunk
(DETACH, TokenHSI, CML or flat) on the normalised, named observation groups; `self.mlp` (the
adapter MLP `adapter_units`, e.g. [1024, 512]) is the policy head (Gaussian actions through
rsl-rl's distribution) or the value head.

Actor and critic: rsl-rl builds two instances of the same class. By default each has its own
trunk (`make_trunk`; TokenHSI's critic is a plain MLP on the `critic` group), the critic with the
extra privileged `critic` group as one more token/input; train both with the auxiliary losses
or copy the pretrained encoders with `critic.load_encoders_from(actor)`.
With `model.shared_trunk` (the paper's design: V(s) = ValueHead(h_transformer)) the critic
builds its trunk on the actor's groups and `link_shared_trunk(actor, critic)` (called by
`build_actor_critic` and `AmpPPO` before the optimiser exists) swaps it for the actor's: the
critic then holds the actor by reference, not as a submodule, so the trunk's parameters are
in the optimiser, in checkpoints and under PPO's gradient clip once (as the actor's), and the
value loss reaches the trunk through the critic's latent. The value head reads
[h; the critic's extra groups flat]. Cost: PPO calls actor(obs) then critic(obs) on the same
TensorDict (rollout and every mini-batch); the critic reuses the h of that actor pass, so one
trunk pass serves both (measured in benchmarks/bench_ppo_iteration.py).

Multi-head critic (CML, any kind): with `value_objectives = [o_1, ..., o_K]` the value MLP
outputs K values. `forward(obs)` — what PPO's value path gets — returns [N, 1], the weighted
sum Σ_k w_k V_k (weights `objective_weights`, default 1; set them to the reward weights so that
the sum is the value of the combined reward). `value_heads(obs)` returns [N, K] in objective
order, for a trainer that computes GAE and normalises advantages per objective.

Export (`as_jit`, `as_onnx`, rsl-rl's API; `detach-run export`): every kind exports as
`FlatPolicy`, the deterministic policy on rsl-rl's flat input, the actor's groups
concatenated in `obs_groups` order (self, env, task; histories time-major, oldest frame
first), with the input normaliser inside: obs [N, D] -> actions [N, num_actions].

Stock rsl-rl code builds these classes from a YAML train config (the run's params/agent.yaml):
`obs_spec` and `model` then arrive as plain dicts and are turned back into `ObsSpec` and the
kind's config class here.

Later training stages (TokenHSI's adapters, CML's incremental learning): the model of the new
stage freezes the previous stage's policy (requires_grad False, input statistics not updated),
adds its new module behind `head_output` and names that module's state-dict prefixes in
`new_parameter_prefixes()`, the keys a checkpoint of the previous stage lacks.
"""

from __future__ import annotations

import copy
from collections.abc import Iterator, Sequence
from itertools import chain
from typing import Any, ClassVar

import torch
import torch.nn as nn
from rsl_rl.models import MLPModel
from rsl_rl.modules import EmpiricalNormalization, HiddenState
from rsl_rl.utils import unpad_trajectories
from tensordict import TensorDict

from detach.config_schema import ModelCfg
from detach.config_validate import Builder
from detach.envs.obs_spec import ObsSpec
from detach.models.adapters import CooperativePolicy, HeadAdapter
from detach.models.cml import CMLCfg, CMLTrunk
from detach.models.detach_net import DetachCfg, DetachFeatures, DetachTrunk
from detach.models.layout import ObsLayout, no_columns, stack_columns
from detach.models.losses import combine_aux_losses
from detach.models.mlp import FlatTrunk, MLPCfg
from detach.models.tokenhsi import ACTIVE_SKILLS, TokenHSICfg, TokenHSITrunk, TokenHSIValueTrunk
from detach.skills import canonical_name, skill_index


class StructuredModel(MLPModel):
    """MLPModel whose latent is `trunk(named normalised groups)`; optional multi-head value output.

    Args (beyond rsl-rl's obs, obs_groups, obs_set, output_dim):
        obs_spec: the env's `ObsSpec`, to reshape the history groups.
        model: the typed model config (`config_class`); `adapter_units`, `activation` and
            `obs_normalization` configure the head MLP and the normaliser.
        distribution_cfg: rsl-rl distribution (actor only).
        value_objectives: names of the value heads (critic only); None = one plain output.
    """

    trunk_class: ClassVar[type[nn.Module]] = FlatTrunk
    config_class: ClassVar[type[ModelCfg]] = MLPCfg
    sum_value_heads: bool = True
    """With several value heads, forward returns their weighted sum [N, 1] (stock PPO); a
    trainer with per-objective GAE (`detach.train.amp_ppo.AmpPPO`) sets False to get [N, K]."""

    def __init__(
        self,
        obs: TensorDict,
        obs_groups: dict[str, list[str]],
        obs_set: str,
        output_dim: int,
        obs_spec: ObsSpec,
        model: ModelCfg,
        distribution_cfg: dict | None = None,
        value_objectives: Sequence[str] | None = None,
    ) -> None:
        obs_spec, model = plain_configs(obs_spec, model)
        if not isinstance(model, self.config_class):
            raise TypeError(f"{type(self).__name__} needs a {self.config_class.__name__}, got {type(model).__name__}")
        cfg, spec = model, obs_spec
        layout = ObsLayout.from_obs(obs, obs_groups[obs_set], spec)
        shared = getattr(cfg, "shared_trunk", False)
        reads_actor_trunk = shared and distribution_cfg is None and obs_set != "actor"
        trunk_layout = layout
        if reads_actor_trunk:
            missing = [g for g in obs_groups["actor"] if g not in layout.groups]
            if missing:
                raise ValueError(f"shared_trunk: the {obs_set} set lacks the actor's groups {missing}")
            trunk_layout = ObsLayout.from_obs(obs, obs_groups["actor"], spec)
        value_only = distribution_cfg is None and not reads_actor_trunk
        trunk = self.make_trunk(trunk_layout, cfg, value_only)
        head_groups = tuple(g for g in layout.groups if g not in trunk_layout.groups)
        objectives = tuple(value_objectives or ())
        if objectives and distribution_cfg is not None:
            raise ValueError("value_objectives is for critics; an actor with distribution_cfg has one action head")
        if objectives and output_dim not in (1, len(objectives)):
            raise ValueError(f"critic output_dim {output_dim} does not match value_objectives {list(objectives)}")
        # read by MLPModel.__init__ through _get_latent_dim
        self._latent_dim = trunk.out_dim + sum(layout.dim(g) for g in head_groups)
        super().__init__(
            obs,
            obs_groups,
            obs_set,
            len(objectives) if objectives else output_dim,
            hidden_dims=self.head_units(cfg, value_only),
            activation=cfg.activation,
            obs_normalization=cfg.obs_normalization,
            distribution_cfg=distribution_cfg,
        )
        self.cfg = cfg
        self.layout = layout
        self.trunk = trunk
        self.reads_actor_trunk = reads_actor_trunk
        self.head_groups = head_groups
        """Groups the head reads directly beside the trunk's h (a shared-trunk critic's extras)."""
        self.value_objectives = objectives
        if objectives:
            self.register_buffer("objective_weights", torch.ones(len(objectives)))

    # ----- hooks of the model kinds -----
    @classmethod
    def make_trunk(cls, layout: ObsLayout, cfg: ModelCfg, value_only: bool) -> nn.Module:
        """The trunk on `layout`; `value_only` for a critic with a trunk of its own."""
        return cls.trunk_class(layout, cfg)

    @classmethod
    def head_units(cls, cfg: ModelCfg, value_only: bool) -> tuple[int, ...]:
        """Hidden widths of the head MLP (`adapter_units` unless a kind's critic differs)."""
        return tuple(cfg.adapter_units)

    def head_output(self, latent: torch.Tensor, obs: TensorDict) -> torch.Tensor:
        """The head's raw output on the latent: the distribution's input (actor) or the values
        (critic). A later training stage's model adds its adapter or cooperative policy here."""
        return self.mlp(latent)

    def new_parameter_prefixes(self) -> tuple[str, ...]:
        """State-dict key prefixes of modules this model adds to the previous training stage's
        (an adapter, a cooperative policy): a checkpoint of that stage lacks exactly these
        keys, so `train.init_from` lets them be missing and requires every other key."""
        return ()

    # ----- rsl-rl API -----
    def _get_latent_dim(self) -> int:
        return self._latent_dim

    def normalized_groups(self, obs: TensorDict) -> dict[str, torch.Tensor]:
        """Concatenate this obs set's groups, normalise, split back by name (histories [N, T, d])."""
        return self.layout.split(super().get_latent(obs))

    def get_latent(
        self, obs: TensorDict, masks: torch.Tensor | None = None, hidden_state: HiddenState = None
    ) -> torch.Tensor:
        groups = self.normalized_groups(obs)
        owner = self._trunk_owner
        if owner is None:
            h = self.trunk_latent(obs, groups)
            self._latent_cache = (obs, h)
        else:
            h = owner.shared_latent(obs)
        if self.head_groups:
            h = torch.cat([h, *(groups[g].flatten(1) for g in self.head_groups)], dim=-1)
        return h

    def trunk_latent(self, obs: TensorDict, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        """h = trunk(normalised groups); DetachModel keeps the intermediates for aux_losses."""
        return self.trunk(groups)

    # ----- shared trunk -----
    _trunk_owner: StructuredModel | None = None
    _latent_cache: tuple[TensorDict, torch.Tensor] | None = None

    @property
    def owns_trunk(self) -> bool:
        """False for a critic linked to the actor's trunk (it has no trunk of its own)."""
        return self._trunk_owner is None

    def share_trunk_of(self, actor: StructuredModel) -> None:
        """Drop this critic's trunk and read `actor`'s from now on (see the module docstring)."""
        if not self.reads_actor_trunk:
            raise ValueError("share_trunk_of: this model was not built as a shared-trunk critic")
        if not actor.owns_trunk or type(actor.trunk) is not type(self.trunk) \
                or actor.trunk.out_dim != self.trunk.out_dim:
            raise ValueError("share_trunk_of: the actor's trunk does not match this critic's")
        del self.trunk
        object.__setattr__(self, "_trunk_owner", actor)  # plain attribute: not a submodule

    def shared_latent(self, obs: TensorDict) -> torch.Tensor:
        """h for the critic that reads this trunk: the latent of this model's last forward pass
        when it was on the very same TensorDict object (consumed once), else a fresh pass."""
        cache, self._latent_cache = self._latent_cache, None
        if cache is not None and cache[0] is obs:
            return cache[1]
        return self.trunk(self.normalized_groups(obs))

    def forward(
        self,
        obs: TensorDict,
        masks: torch.Tensor | None = None,
        hidden_state: HiddenState = None,
        stochastic_output: bool = False,
    ) -> torch.Tensor:
        """rsl-rl's `MLPModel.forward` with the head behind `head_output`."""
        obs = unpad_trajectories(obs, masks) if masks is not None and not self.is_recurrent else obs
        out = self.head_output(self.get_latent(obs, masks, hidden_state), obs)
        if self.distribution is not None:
            if stochastic_output:
                self.distribution.update(out)
                return self.distribution.sample()
            return self.distribution.deterministic_output(out)
        if self.value_objectives and self.sum_value_heads:
            return (out * self.objective_weights).sum(-1, keepdim=True)
        return out

    def as_jit(self) -> nn.Module:
        """The deterministic policy traced to TorchScript (a ScriptModule: rsl-rl's
        `export_policy_to_jit` scripts it as it is), on the CPU."""
        policy = FlatPolicy(self)
        with torch.no_grad():
            return torch.jit.trace(policy, policy.get_dummy_inputs(), check_trace=False)

    def as_onnx(self, verbose: bool = False) -> nn.Module:
        """The deterministic policy for `torch.onnx.export` (rsl-rl's `_OnnxMLPModel` API)."""
        return FlatPolicy(self, verbose)

    # ----- multi-head critic -----
    def value_heads(self, obs: TensorDict) -> torch.Tensor:
        """Per-objective values [N, K] (order of `value_objectives`)."""
        if not self.value_objectives:
            raise ValueError(f"{type(self).__name__} was built without value_objectives")
        return self.head_output(self.get_latent(obs), obs)

    def set_objective_weights(self, weights: Sequence[float] | torch.Tensor) -> None:
        """w_k of forward's Σ_k w_k V_k (e.g. task and style reward weights)."""
        w = torch.as_tensor(weights, dtype=self.objective_weights.dtype, device=self.objective_weights.device)
        if w.shape != self.objective_weights.shape:
            raise ValueError(f"expected {len(self.value_objectives)} weights for {list(self.value_objectives)}")
        self.objective_weights.copy_(w)

    # ----- uniform hooks for trainers (no-ops except in DetachModel) -----
    def input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(weight [out, in], input columns [in, F]) of every layer that reads the normalised
        observation directly (column c of the weight reads the normaliser's outputs
        cols[c] in every frame; -1 none): the trunk's own and the head's first layer, which
        reads the inputs the trunk passes on and `head_groups`. `train.init_normalizers:
        merge` zeroes the columns of inputs the source run never saw vary."""
        own = self.owns_trunk
        trunk_out = self.trunk.output_columns() if own else no_columns(self._owner_out_dim())
        head = stack_columns(trunk_out, *(self.layout.columns(g) for g in self.head_groups))
        first = next(m for m in self.mlp if isinstance(m, nn.Linear))
        return (self.trunk.input_weights() if own else []) + [(first.weight, head)]

    def _owner_out_dim(self) -> int:
        return self._latent_dim - sum(self.layout.dim(g) for g in self.head_groups)

    def aux_losses(self, obs: TensorDict) -> dict[str, torch.Tensor]:
        """Auxiliary loss terms; none for the baselines."""
        return {}

    def head_parameters(self) -> Iterator[nn.Parameter]:
        """The adapter MLP and the distribution's parameters (e.g. the action std)."""
        yield from self.mlp.parameters()
        if self.distribution is not None:
            yield from self.distribution.parameters()


class DetachModel(StructuredModel):
    """DETACH (and its ablations A1/A2 through `use_env_encoder` / `use_self_encoder`).

    Trainer API for the 3-stage protocol:
        aux_losses(obs, reuse_forward=False) -> {name: scalar}: unweighted terms on the same
            normalised inputs as forward; runs encoders + fusion again (never φ). With
            reuse_forward=True and the very TensorDict object of the last training-mode forward
            pass with grad (a PPO update: actor(batch.observations, ...), then
            actor.aux_losses(batch.observations, reuse_forward=True), then ONE backward of
            PPO loss + aux loss) it reuses that pass's encoder and fusion outputs instead,
            saving ~1/3 of the aux cost; do not use it if that forward's graph was already
            backpropagated. Terms:
            L_env (Decoder_env reconstruction), L_self (temporal prediction), R_decouple
            (‖Corr(z_env, z_self)‖_F²), MI (correlation-based I(z_env, z_self)), R_temporal,
            R_semantic_env, R_semantic_self, R_semantic (α/β-weighted sum), L_fusion_quality
            (‖f_cross - (f_env + f_self)‖² + λ_disentangle·MI), R1, R2 (‖θ - θ*‖², 0 before
            `snapshot_encoders`), R3 (fusion diversity, `regularizers.r3_mode`). Terms whose
            module an ablation removed are 0; the keys are always the same.
        aux_loss(obs, stage, reuse_forward=False) -> scalar: the weighted sum for stage
            pretrain | fusion | joint
            (see `losses.combine_aux_losses`).
        encoder_parameters(), pretrain_parameters(), fusion_parameters(), head_parameters()
        freeze_encoders(), unfreeze_encoders(), snapshot_encoders(), load_encoders_from(other)
    Pre-training without PPO: call `update_normalization(obs)` yourself so the inputs are
    normalised as they will be during RL.
    """

    trunk_class = DetachTrunk
    config_class = DetachCfg
    trunk: DetachTrunk
    _forward_cache: tuple[TensorDict, dict[str, torch.Tensor], DetachFeatures] | None = None

    def trunk_latent(self, obs: TensorDict, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        feats = self.trunk.encode(groups)
        # Keep the encoder/fusion outputs of a training forward pass for aux_losses on the same obs.
        self._forward_cache = (obs, groups, feats) if torch.is_grad_enabled() and self.training else None
        return self.trunk.latent(groups, feats)

    def aux_losses(self, obs: TensorDict, reuse_forward: bool = False) -> dict[str, torch.Tensor]:
        cache, self._forward_cache = self._forward_cache, None
        if reuse_forward and cache is not None and cache[0] is obs:
            return self.trunk.aux_losses(cache[1], self.cfg.regularizers, cache[2])
        return self.trunk.aux_losses(self.normalized_groups(obs), self.cfg.regularizers)

    def aux_loss(self, obs: TensorDict, stage: str, reuse_forward: bool = False) -> torch.Tensor:
        return combine_aux_losses(self.aux_losses(obs, reuse_forward), stage, self.cfg.regularizers)

    def encoder_parameters(self) -> Iterator[nn.Parameter]:
        """θ_env and θ_self (Φ_env, Φ_self)."""
        return chain.from_iterable(m.parameters() for m in self.trunk.encoder_modules())

    def pretrain_parameters(self) -> Iterator[nn.Parameter]:
        """Stage 1: the encoders plus Decoder_env, Decoder_self and f_pred."""
        mods = self.trunk.encoder_modules() + self.trunk.pretrain_head_modules()
        return chain.from_iterable(m.parameters() for m in mods)

    def fusion_parameters(self) -> Iterator[nn.Parameter]:
        """Stage 2 (besides the heads): P_env, P_self, fusion, tokens and φ."""
        return self.trunk.fusion_parameters()

    def freeze_encoders(self) -> None:
        """Stage 2: θ_env, θ_self get requires_grad=False (Adam skips params without grad)."""
        for p in self.encoder_parameters():
            p.requires_grad_(False)

    def unfreeze_encoders(self) -> None:
        for p in self.encoder_parameters():
            p.requires_grad_(True)

    def snapshot_encoders(self) -> None:
        """Record θ*_env, θ*_self (call at the end of pre-training); R1/R2 measure drift from them."""
        self.trunk.snapshot_encoders()

    @torch.no_grad()
    def load_encoders_from(self, other: DetachModel) -> None:
        """Copy encoders, their pre-training heads and anchors from another DETACH model (actor -> critic)."""
        t, o = self.trunk, other.trunk
        names = ("env_encoder", "env_decoder", "self_encoder", "self_decoder", "predictor", "env_anchor", "self_anchor")
        for name in names:
            mine, theirs = getattr(t, name), getattr(o, name)
            if (mine is None) != (theirs is None):
                raise ValueError(f"cannot copy {name}: present in only one of the two models")
            if mine is not None:
                mine.load_state_dict(theirs.state_dict())


def link_shared_trunk(actor: nn.Module, critic: nn.Module) -> None:
    """Give a shared-trunk critic the actor's trunk; a no-op for any other pair."""
    if getattr(critic, "reads_actor_trunk", False) and getattr(critic, "owns_trunk", False):
        critic.share_trunk_of(actor)


class TokenHSIModel(StructuredModel):
    """TokenHSI (`detach.models.tokenhsi`): tokenizers, masked transformer, action-token head;
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
            if float(mean[task[skill_index(skill)]]) > 0.0:
                continue  # the source ran it: its own tokenizer is trained
            self.trunk.copy_task_tokenizer(skill, source, mean[env], scale[env])
            done.append(f"{canonical_name(skill)} <- {canonical_name(source)}")
        return done


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


class MLPBaselineModel(StructuredModel):
    """Plain MLP on the concatenated normalised groups (same as rsl-rl's MLPModel)."""

    trunk_class = FlatTrunk


def plain_configs(obs_spec: ObsSpec | dict, model: ModelCfg | dict) -> tuple[ObsSpec, ModelCfg]:
    """`obs_spec` and `model` as the typed objects, also when a YAML train config (params/
    agent.yaml, read by stock rsl-rl code) gives them as dicts."""
    if isinstance(obs_spec, dict):
        obs_spec = ObsSpec(**obs_spec)
    if isinstance(model, dict):
        builder = Builder({}, "train_cfg (model)")
        try:
            cls = ModelCfg.kind_class(str(model.get("kind")))
        except ValueError as exc:
            raise builder.error(("kind",), str(exc)) from None
        model = builder.build(cls, model, ())
    return obs_spec, model


class FlatPolicy(nn.Module):
    """A `StructuredModel` actor as rsl-rl exports policies: the deterministic action of the
    flat observation `obs` [N, D] (the actor's groups concatenated in `obs_groups` order, raw:
    the input normaliser is inside). A deep copy on the CPU in eval mode; `groups`, `dims` and
    `history` describe the layout of `obs` (`detach.runs.export` writes them beside the file)."""

    is_recurrent: bool = False

    def __init__(self, model: StructuredModel, verbose: bool = False) -> None:
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
