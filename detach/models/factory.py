"""ModelCfg + ObsSpec -> rsl-rl actor/critic configs, or the models themselves (through the
network `register_model` gave the config's kind).

`rsl_rl_model_cfgs` gives the `actor` and `critic` entries of rsl-rl's train_cfg (the typed
model config and obs spec travel as objects; rsl-rl deep-copies them). `build_actor_critic`
builds both through rsl-rl's own `resolve_class` path, for tests and evaluation.
Observation sets: {"actor": ["self", "env", "task"], "critic": ["self", "env", "task", "critic"]}.
"""

from __future__ import annotations

from rsl_rl.utils import resolve_class
from tensordict import TensorDict

from detach.config.schema import ModelCfg
from detach.envs.obs_spec import ObsSpec
from detach.models.registry import model_class
from detach.models.structured import StructuredModel, link_shared_trunk

DEFAULT_OBS_GROUPS: dict[str, list[str]] = {
    "actor": ["self", "env", "task"],
    "critic": ["self", "env", "task", "critic"],
}

GAUSSIAN = "rsl_rl.modules.distribution:GaussianDistribution"


def class_path(cls: type) -> str:
    """'package.module:Class', the form rsl-rl's resolve_class accepts."""
    return f"{cls.__module__}:{cls.__qualname__}"


def rsl_rl_model_cfgs(model_cfg: ModelCfg, obs_spec: ObsSpec, default_std: float) -> tuple[dict, dict]:
    """(actor_cfg, critic_cfg) for rsl-rl's train_cfg["actor"] / ["critic"].

    The actor gets a Gaussian action distribution with state-independent std
    (`init_noise_std`, or `default_std` -- the character's -- when it is None); the critic gets
    one value head per `critic_objectives` entry when there are several (see `detach.models.structured`).
    """
    common = {"class_name": class_path(model_class(model_cfg)), "obs_spec": obs_spec, "model": model_cfg}
    std = default_std if model_cfg.init_noise_std is None else model_cfg.init_noise_std
    actor = {**common, "distribution_cfg": {"class_name": GAUSSIAN, "init_std": std,
                                            "learn_std": model_cfg.learn_noise_std}}
    critic = dict(common)
    if len(model_cfg.critic_objectives) > 1:
        critic["value_objectives"] = list(model_cfg.critic_objectives)
    return actor, critic


def build_actor_critic(
    model_cfg: ModelCfg,
    obs_spec: ObsSpec,
    obs: TensorDict,
    obs_groups: dict[str, list[str]] | None = None,
    num_actions: int | None = None,
    default_std: float = 1.0,
) -> tuple[StructuredModel, StructuredModel]:
    """Instantiate (actor, critic) as rsl-rl's PPO.construct_algorithm + AmpPPO do (trunk linked)."""
    groups = obs_groups or DEFAULT_OBS_GROUPS
    actor_cfg, critic_cfg = rsl_rl_model_cfgs(model_cfg, obs_spec, default_std)
    actor_cls, actor_kwargs = resolve_class(actor_cfg)
    critic_cls, critic_kwargs = resolve_class(critic_cfg)
    n_act = obs_spec.num_actions if num_actions is None else num_actions
    actor = actor_cls(obs, groups, "actor", n_act, **actor_kwargs)
    critic = critic_cls(obs, groups, "critic", 1, **critic_kwargs)
    link_shared_trunk(actor, critic)
    return actor, critic
