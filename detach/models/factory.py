"""ModelCfg + ObsSpec -> rsl-rl actor/critic configs, or the models themselves.

`rsl_rl_model_cfgs` gives the `actor` and `critic` entries of rsl-rl's train_cfg (plain data
only: they are deep-copied by rsl-rl and may be dumped to YAML). `build_actor_critic` builds
both through rsl-rl's own `resolve_class` path, for tests and evaluation.
Observation sets: {"actor": ["self", "env", "task"], "critic": ["self", "env", "task", "critic"]}.
"""

from __future__ import annotations

from typing import Any

from rsl_rl.utils import resolve_class
from tensordict import TensorDict

from detach.config_schema import EnvCfg, ModelCfg, action_std
from detach.config_validate import to_plain
from detach.envs.obs_spec import ObsSpec
from detach.models.rsl_rl_models import (
    CMLModel,
    DetachModel,
    MLPBaselineModel,
    StructuredModel,
    TokenHSIModel,
    link_shared_trunk,
)

MODEL_CLASSES: dict[str, type[StructuredModel]] = {
    "detach": DetachModel,
    "tokenhsi": TokenHSIModel,
    "cml": CMLModel,
    "mlp": MLPBaselineModel,
}

DEFAULT_OBS_GROUPS: dict[str, list[str]] = {
    "actor": ["self", "env", "task"],
    "critic": ["self", "env", "task", "critic"],
}

GAUSSIAN = "rsl_rl.modules.distribution:GaussianDistribution"


def class_path(cls: type) -> str:
    """'package.module:Class', the form rsl-rl's resolve_class accepts."""
    return f"{cls.__module__}:{cls.__qualname__}"


def rsl_rl_model_cfgs(model_cfg: ModelCfg, obs_spec: ObsSpec) -> tuple[dict, dict]:
    """(actor_cfg, critic_cfg) for rsl-rl's train_cfg["actor"] / ["critic"].

    The actor gets a Gaussian action distribution with state-independent std
    (`init_noise_std`); the critic gets one value head per `critic_objectives` entry (its
    forward returns their weighted sum [N, 1]; see `rsl_rl_models`).
    """
    if model_cfg.kind not in MODEL_CLASSES:
        raise ValueError(f"model.kind must be one of {sorted(MODEL_CLASSES)}, got {model_cfg.kind!r}")
    common = {
        "class_name": class_path(MODEL_CLASSES[model_cfg.kind]),
        "obs_spec": obs_spec.to_dict(),
        "model": to_plain(model_cfg),
    }
    # A resolved run config has the number; a bare ModelCfg gets the default character's.
    std = action_std(model_cfg.init_noise_std, EnvCfg.character)
    actor = {**common, "distribution_cfg": {"class_name": GAUSSIAN, "init_std": std}}
    critic = {**to_plain(common), "value_objectives": list(model_cfg.critic_objectives)}
    return to_plain(actor), critic


def build_actor_critic(
    model_cfg: ModelCfg,
    obs_spec: ObsSpec,
    obs: TensorDict,
    obs_groups: dict[str, list[str]] | None = None,
    num_actions: int | None = None,
) -> tuple[StructuredModel, StructuredModel]:
    """Instantiate (actor, critic) as rsl-rl's PPO.construct_algorithm + AmpPPO do (trunk linked)."""
    groups = obs_groups or DEFAULT_OBS_GROUPS
    actor_cfg, critic_cfg = rsl_rl_model_cfgs(model_cfg, obs_spec)
    actor_cls, actor_kwargs = resolve_class(actor_cfg)
    critic_cls, critic_kwargs = resolve_class(critic_cfg)
    n_act = obs_spec.num_actions if num_actions is None else num_actions
    actor = actor_cls(obs, groups, "actor", n_act, **actor_kwargs)
    critic = critic_cls(obs, groups, "critic", 1, **critic_kwargs)
    link_shared_trunk(actor, critic)
    return actor, critic
