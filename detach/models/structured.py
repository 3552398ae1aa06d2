"""`StructuredModel`, the base of every network of the study as an rsl-rl-lib actor/critic model.

rsl-rl 5.x builds actor and critic as `cls(obs, obs_groups, obs_set, output_dim, **cfg)` and
calls only the `MLPModel` API (forward with `stochastic_output`, `get_output_log_prob`,
`output_distribution_params`, `output_entropy`, `get_kl_divergence`, `update_normalization`,
`reset`, `get_hidden_state`). A model kind is one module (`detach.models.mlp`, `cml`, `tokenhsi`,
`detach_net`, or one outside the package) holding its config class, its trunk and a subclass of
`StructuredModel`, an `MLPModel` whose `get_latent` runs that trunk on the normalised, named
observation groups, registered with `detach.models.registry.register_model`; `self.mlp` (the
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
`detach.models.flat_policy.FlatPolicy`, the deterministic policy on rsl-rl's flat input, the actor's groups
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

from collections.abc import Iterator, Sequence
from typing import ClassVar

import torch
import torch.nn as nn
from rsl_rl.models import MLPModel
from rsl_rl.modules import HiddenState
from rsl_rl.utils import unpad_trajectories
from tensordict import TensorDict

from detach.config.schema import ModelCfg
from detach.config.validate import Builder
from detach.envs.obs_spec import ObsSpec
from detach.models.flat_policy import FlatPolicy
from detach.models.layout import ObsLayout, no_columns, stack_columns


class StructuredModel(MLPModel):
    """MLPModel whose latent is `trunk(named normalised groups)`; optional multi-head value output.

    Args (beyond rsl-rl's obs, obs_groups, obs_set, output_dim):
        obs_spec: the env's `ObsSpec`, to reshape the history groups.
        model: the typed model config (`config_class`); `adapter_units`, `activation` and
            `obs_normalization` configure the head MLP and the normaliser.
        distribution_cfg: rsl-rl distribution (actor only).
        value_objectives: names of the value heads (critic only); None = one plain output.
    """

    trunk_class: ClassVar[type[nn.Module]]
    """The trunk, built as `trunk_class(layout, cfg)` unless a kind overrides `make_trunk`."""
    config_class: ClassVar[type[ModelCfg]]
    """The kind's config class (a `ModelCfg` subclass): `register_model` maps it to this network."""
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

    def training_only_prefixes(self) -> tuple[str, ...]:
        """State-dict key prefixes of modules that only training reads (pre-training heads,
        regulariser anchors): a shipped policy leaves them out (`detach-run export --format
        policy`) and loading it keeps their initial values, which never reach an action."""
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

    def frozen_features(self, obs: TensorDict) -> TensorDict | None:
        """What this model's frozen layers compute from `obs` [B], for a trainer to attach to
        the rollout's observations once per update (`frozen_features_key`); None: nothing
        frozen to reuse (DetachModel's stage-2 encoders are the one case)."""
        return None

    def frozen_features_key(self) -> str:
        """The key under which `frozen_features` are attached to observations: this model's own
        (a critic with a trunk of its own has other encoders and must not read them)."""
        return f"frozen_features_{id(self)}"

    def head_parameters(self) -> Iterator[nn.Parameter]:
        """The adapter MLP and the distribution's parameters (e.g. the action std)."""
        yield from self.mlp.parameters()
        if self.distribution is not None:
            yield from self.distribution.parameters()


def new_parameter_prefixes(module: nn.Module) -> tuple[str, ...]:
    """`module.new_parameter_prefixes()`, or none for a model without the method (rsl-rl's MLP)."""
    return tuple(getattr(module, "new_parameter_prefixes", lambda: ())())


def training_only_prefixes(module: nn.Module) -> tuple[str, ...]:
    """`module.training_only_prefixes()`, or none for a model without the method (rsl-rl's MLP)."""
    return tuple(getattr(module, "training_only_prefixes", lambda: ())())


def link_shared_trunk(actor: nn.Module, critic: nn.Module) -> None:
    """Give a shared-trunk critic the actor's trunk; a no-op for any other pair."""
    if getattr(critic, "reads_actor_trunk", False) and getattr(critic, "owns_trunk", False):
        critic.share_trunk_of(actor)


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

