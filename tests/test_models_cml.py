"""CML as published (configs/models/cml.yaml) and its incremental learning
(configs/models/cml_incremental.yaml): the frozen meta policy, the cooperative policy's
per-action-dimension mix, what trains, and that a meta checkpoint starts the mix at the meta
action; the multi-objective critic and body-part discriminators stay in both stages."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch
import torch.nn as nn
from tensordict import TensorDict

from detach.config import ConfigError, resolve
from detach.envs.obs_spec import ObsSpec
from detach.models import build_actor_critic
from detach.models.cml import CMLCfg
from detach.train.setup import build_runner

ROOT = Path(__file__).resolve().parents[1]
SPEC = ObsSpec(self_steps=3, self_dim=10, env_steps=2, env_dim=3 + 2 * 3 + 33 + 16, height_map_cells=16,
               num_skills=4, critic_dim=10 + 58 + 4 + 5, amp_steps=2, amp_dim=8, num_actions=6)
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=4",
        "train.num_mini_batches=2", "train.num_learning_epochs=1", "env.episode_length=40"]


def model_cfg(name: str, *overrides: str) -> CMLCfg:
    """The `model` section of a shipped model YAML."""
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", name, list(overrides)).model
    assert isinstance(cfg, CMLCfg)
    return cfg


def random_obs(n: int = 8, seed: int = 0) -> TensorDict:
    g = torch.Generator().manual_seed(seed)
    obs = {k: torch.randn(n, d, generator=g) for k, d in SPEC.group_dims().items()}
    obs["task"] = nn.functional.one_hot(torch.arange(n) % SPEC.num_skills, SPEC.num_skills).float()
    return TensorDict(obs, batch_size=[n])


def build(name: str, seed: int = 0):
    torch.manual_seed(seed)
    return build_actor_critic(model_cfg(name), SPEC, random_obs())


def phase_b_from_phase_a(seed_a: int = 1, seed_b: int = 2):
    """A trained-looking meta model (normaliser statistics set) and an incremental model loaded
    from its state dicts; returns (meta actor, actor, critic, obs, missing keys)."""
    meta, meta_critic = build("cml", seed_a)
    obs = random_obs(seed=3)
    meta.update_normalization(obs)
    meta_critic.update_normalization(obs)
    actor, critic = build("cml_incremental", seed_b)
    loaded = actor.load_state_dict(meta.state_dict(), strict=False)
    assert not loaded.unexpected_keys
    critic.load_state_dict(meta_critic.state_dict())
    return meta, actor, critic, obs, set(loaded.missing_keys)


def test_cml_yamls_keep_body_part_discriminators_and_the_multi_objective_critic() -> None:
    for name, incremental in (("cml", False), ("cml_incremental", True)):
        cfg = resolve(ROOT / "configs/tasks/lh1.yaml", name)
        assert cfg.model.incremental is incremental
        assert cfg.model.critic_objectives == ("task", "disc_upper", "disc_lower")
        assert cfg.train.amp.body_parts == ("upper", "lower") and cfg.train.per_objective_advantage_norm
    _, critic = build("cml_incremental")
    assert critic.value_objectives == ("task", "disc_upper", "disc_lower")
    with pytest.raises(ConfigError, match=r"model\.incremental: .*shared_trunk"):
        model_cfg("cml_incremental", "model.shared_trunk=true")


def test_incremental_actor_freezes_the_meta_policy_and_trains_the_cooperative_one() -> None:
    actor, critic = build("cml_incremental")
    trainable = {n for n, p in actor.named_parameters() if p.requires_grad}
    assert trainable == {n for n, _ in actor.named_parameters() if n.startswith("cooperative.")} \
        | {"distribution.std_param"}
    assert any(n.startswith("cooperative.trunk.gru.") for n in trainable)  # a CML network of its own
    assert all(p.requires_grad for p in critic.parameters())
    assert actor.new_parameter_prefixes() == ("cooperative.",) and critic.new_parameter_prefixes() == ()
    base, _ = build("cml")
    assert base.new_parameter_prefixes() == () and all(p.requires_grad for p in base.parameters())


def test_a_meta_checkpoint_loads_with_only_the_cooperative_policy_missing_and_the_mix_starts_at_it() -> None:
    meta, actor, critic, obs, missing = phase_b_from_phase_a()
    assert missing == {k for k in actor.state_dict() if k.startswith("cooperative.")}
    with torch.no_grad():
        assert torch.equal(actor(obs), meta(obs))
        assert torch.equal(actor.mixing_weights(obs), torch.full((8, SPEC.num_actions), 0.5))


def test_the_executed_mean_mixes_meta_and_cooperative_actions_per_dimension() -> None:
    meta, actor, _, obs, _ = phase_b_from_phase_a()
    with torch.no_grad():
        for p in actor.cooperative.head[-1].parameters():
            p.normal_(0.0, 0.5)
        raw = torch.cat([obs[g] for g in ("self", "env", "task")], dim=-1)
        delta, weight = actor.cooperative(raw)
        a_meta, a_coop = meta(obs), meta(obs) + delta
        assert ((weight > 0) & (weight < 1)).all() and weight.std() > 0.05  # varies per dimension
        assert torch.allclose(actor(obs), (1 - weight) * a_meta + weight * a_coop, atol=1e-6)
    actions = actor(obs, stochastic_output=True).detach()
    (-actor.get_output_log_prob(actions).mean()).backward()
    for name, p in actor.named_parameters():
        assert (p.grad is not None) == name.startswith(("cooperative.", "distribution.")), name


def test_ppo_on_the_incremental_stage_moves_only_the_cooperative_policy(tmp_path: Path) -> None:
    """Phase A (cml, follow) trains an iteration; its weights are the meta policy of phase B
    (cml_incremental on climb), which trains one PPO iteration (two optimiser steps) with three
    value heads and two body-part discriminators: the cooperative policy (its normaliser
    included), the std and the critic move; the meta policy and its input statistics stay
    bit-identical."""
    base_cfg = resolve(ROOT / "configs/tasks/follow.yaml", "cml", [*TINY, "train.max_iterations=1"])
    _env, base = build_runner(base_cfg, None, "cpu", progress=False)
    base.learn(1)
    cfg = resolve(ROOT / "configs/tasks/climb.yaml", "cml_incremental", [*TINY, "train.max_iterations=1"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    alg = runner.alg
    assert alg.num_objectives == 3 and alg.per_objective_norm and set(alg.discriminators) == {"upper", "lower"}
    actor, critic = alg.actor, alg.critic
    actor.load_state_dict(base.alg.actor.state_dict(), strict=False)
    critic.load_state_dict(base.alg.critic.state_dict())
    obs = env.get_observations()
    with torch.no_grad():  # equal up to float rounding: CPU kinds differ in the last bits here
        assert torch.allclose(actor(obs), base.alg.actor(obs), atol=1e-6, rtol=1e-6)
    before = {k: v.clone() for k, v in actor.state_dict().items()}
    critic_before = {k: v.clone() for k, v in critic.state_dict().items()}
    runner.learn(1)
    after = actor.state_dict()
    moved = {k for k, v in after.items() if not torch.equal(v, before[k])}
    assert moved == {k for k in before if k.startswith("cooperative.")} | {"distribution.std_param"}
    assert int(after["obs_normalizer.count"]) == int(base.alg.actor.obs_normalizer.count) > 0
    assert int(after["cooperative.obs_normalizer.count"]) > 0
    assert any(k.startswith("mlp.") for k, v in critic.state_dict().items() if not torch.equal(v, critic_before[k]))
