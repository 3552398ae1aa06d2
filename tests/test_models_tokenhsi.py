"""TokenHSI as published (configs/models/tokenhsi.yaml) and its adapter stage
(configs/models/tokenhsi_adapt.yaml): tokenizers, masking, critic, what is frozen and what
trains, and that a base checkpoint starts the adapted model with the base model's actions."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch
import torch.nn as nn
from tensordict import TensorDict

from detach.config import ConfigError, resolve
from detach.envs.obs_spec import ObsSpec
from detach.models import build_actor_critic
from detach.models.tokenhsi import TokenHSICfg
from detach.skills import skill_class, skill_names
from detach.train.run_config import resolve_run
from detach.train.setup import build_runner

ROOT = Path(__file__).resolve().parents[1]
SPEC = ObsSpec(self_steps=3, self_dim=10, env_steps=2, env_dim=3 + 2 * 3 + 33 + 16, height_map_cells=16,
               num_skills=4, critic_dim=10 + 58 + 4 + 5, amp_steps=2, amp_dim=8, num_actions=6)
"""A small spec whose env frame has every named part (target 3, path 6, object 33, height map 16)."""
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=4",
        "train.num_mini_batches=2", "train.num_learning_epochs=1", "env.episode_length=40"]


def model_cfg(name: str, *overrides: str) -> TokenHSICfg:
    """The `model` section of a shipped model YAML."""
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", name, list(overrides)).model
    assert isinstance(cfg, TokenHSICfg)
    return cfg


def skill_obs(n: int = 8, seed: int = 0) -> TensorDict:
    """Random groups with a real one-hot: sample i runs skill i mod 4."""
    g = torch.Generator().manual_seed(seed)
    obs = {k: torch.randn(n, d, generator=g) for k, d in SPEC.group_dims().items()}
    obs["task"] = nn.functional.one_hot(torch.arange(n) % SPEC.num_skills, SPEC.num_skills).float()
    return TensorDict(obs, batch_size=[n])


def build(name: str, seed: int = 0, **changes):
    torch.manual_seed(seed)
    cfg = dataclasses.replace(model_cfg(name), **changes)
    return build_actor_critic(cfg, SPEC, skill_obs())


# ----------------------------------------------------------------------------- base stage
def test_network_sizes_come_from_the_yaml() -> None:
    actor, critic = build("tokenhsi")
    trunk = actor.trunk
    assert len(trunk.transformer.attention) == 4 and trunk.transformer.attention[0].heads == 2
    assert trunk.transformer.feed_forward[0][0].out_features == 512 and trunk.out_dim == 64
    widths = [m.out_features for m in trunk.self_tokenizer if isinstance(m, nn.Linear)]
    assert widths == [256, 128, 64]
    assert list(trunk.task_tokenizers) == list(skill_names())
    assert [m.out_features for m in actor.mlp if isinstance(m, nn.Linear)] == [1024, 512, 6]
    assert not any("pos" in name for name, _ in trunk.named_parameters())  # TokenHSI: no positional embedding
    assert [m.out_features for m in critic.mlp if isinstance(m, nn.Linear)] == [2048, 1024, 512, 1]


def test_each_task_tokenizer_reads_its_skills_parts_of_the_newest_env_frame() -> None:
    actor, _ = build("tokenhsi")
    fields = SPEC.env_fields()
    for skill, tokenizer in actor.trunk.task_tokenizers.items():
        width = sum(fields[p].stop - fields[p].start for p in skill_class(skill).task_observation)
        assert tokenizer[0].in_features == width, skill
    assert actor.trunk.task_tokenizers["follow"][0].in_features == 3 + 6 + 16  # target, path, height map
    assert actor.trunk.self_tokenizer[0].in_features == SPEC.self_dim  # the current frame only
    obs = skill_obs()
    older = obs.clone()  # every frame but the newest changes: the actions do not
    older["self"][:, :-SPEC.self_dim] += 3.0
    older["env"][:, :-SPEC.env_dim] += 3.0
    with torch.no_grad():
        assert torch.equal(actor(obs), actor(older))


def test_only_the_current_skills_task_token_is_visible() -> None:
    actor, _ = build("tokenhsi")
    obs = skill_obs()
    active = obs["task"].argmax(-1)
    with torch.no_grad():
        before = actor(obs)
        for index, skill in enumerate(skill_names()):
            for p in actor.trunk.task_tokenizers[skill].parameters():
                p.add_(0.5 * torch.randn_like(p))
            after = actor(obs)
            assert torch.equal(after[active != index], before[active != index]), skill
            assert not torch.allclose(after[active == index], before[active == index]), skill
            before = after
    follow = active == 0  # follow's token does not read the object: its actions ignore it
    moved = obs.clone()
    moved["env"][:, -SPEC.env_dim:][:, SPEC.env_fields()["object"]] += 3.0
    with torch.no_grad():
        assert torch.equal(actor(moved)[follow], actor(obs)[follow])
        assert not torch.allclose(actor(moved)[~follow], actor(obs)[~follow])


def test_the_critic_is_a_separate_mlp_on_the_full_newest_observation() -> None:
    actor, critic = build("tokenhsi")
    obs = skill_obs()
    others = obs.clone()
    for group in ("self", "env", "task"):
        others[group] = others[group] + 1.0
    moved = obs.clone()
    moved["critic"] = moved["critic"] + 1.0
    with torch.no_grad():
        assert torch.equal(critic(obs), critic(others))
        assert not torch.allclose(critic(moved), critic(obs))
    assert not {id(p) for p in actor.parameters()} & {id(p) for p in critic.parameters()}


# ----------------------------------------------------------------------------- adapter stage
ADAPTED = ("trunk.task_tokenizers.climb.", "trunk.task_tokenizers.sit.", "adapter.")


def test_the_adapter_stage_trains_exactly_the_new_skills_tokenizers_and_the_adapter() -> None:
    actor, critic = build("tokenhsi_adapt")
    assert actor.cfg.adapt_skills == ("climb", "sit")
    trainable = {n for n, p in actor.named_parameters() if p.requires_grad}
    assert trainable == {n for n, _ in actor.named_parameters() if n.startswith(ADAPTED)} | {"distribution.std_param"}
    assert all(p.requires_grad for p in critic.parameters())
    assert actor.new_parameter_prefixes() == ("adapter.",) and critic.new_parameter_prefixes() == ()
    assert [b.weight.shape for b in actor.adapter.branches] == [(1024, 64), (512, 1024)]
    # A PPO-like loss reaches the adapter and the active new skills' tokenizers, nothing frozen.
    obs = skill_obs()
    actions = actor(obs, stochastic_output=True).detach()
    (-actor.get_output_log_prob(actions).mean() + critic(obs).pow(2).mean()).backward()
    for name, p in actor.named_parameters():
        assert (p.grad is not None and bool(p.grad.abs().sum() > 0)) == (name in trainable), name


def test_a_base_checkpoint_loads_with_only_the_adapter_missing_and_acts_the_same() -> None:
    base_actor, base_critic = build("tokenhsi", seed=1)
    obs = skill_obs(seed=2)
    base_actor.update_normalization(obs)
    base_critic.update_normalization(obs)
    actor, critic = build("tokenhsi_adapt", seed=2)
    loaded = actor.load_state_dict(base_actor.state_dict(), strict=False)
    assert not loaded.unexpected_keys
    assert set(loaded.missing_keys) == {k for k in actor.state_dict() if k.startswith(actor.new_parameter_prefixes())}
    critic.load_state_dict(base_critic.state_dict())
    with torch.no_grad():
        assert torch.equal(actor(obs), base_actor(obs))
        assert torch.equal(critic(obs), base_critic(obs))


def test_adapter_stage_config_errors_name_the_key() -> None:
    with pytest.raises(ConfigError, match=r"model\.adapt_skills: unknown skill 'jump'"):  # when completed
        resolve_run(ROOT / "configs/tasks/follow.yaml", "tokenhsi_adapt", ["model.adapt_skills=[jump]"])
    with pytest.raises(ConfigError, match=r"model\.adapt_skills: .*shared_trunk"):
        model_cfg("tokenhsi_adapt", "model.shared_trunk=true")
    assert model_cfg("tokenhsi_adapt", "model.adapt_skills=[traj]").adapt_skills == ("traj",)


def test_ppo_on_the_adapter_stage_moves_only_the_adapted_parts(tmp_path: Path) -> None:
    """Phase A (tokenhsi, follow) trains an iteration; its weights start phase B (tokenhsi_adapt
    on climb), which trains one PPO iteration (two optimiser steps): the climb tokenizer, the adapter, the std and
    the critic move; every other actor parameter and the actor's input statistics stay
    bit-identical (sit never runs here, so its tokenizer gets zero gradient and stays too)."""
    base_cfg = resolve(ROOT / "configs/tasks/follow.yaml", "tokenhsi", [*TINY, "train.max_iterations=1"])
    _env, base = build_runner(base_cfg, None, "cpu", progress=False)
    base.learn(1)
    cfg = resolve(ROOT / "configs/tasks/climb.yaml", "tokenhsi_adapt", [*TINY, "train.max_iterations=1"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    actor, critic = runner.alg.actor, runner.alg.critic
    actor.load_state_dict(base.alg.actor.state_dict(), strict=False)
    critic.load_state_dict(base.alg.critic.state_dict())
    obs = env.get_observations()
    with torch.no_grad():
        assert torch.equal(actor(obs), base.alg.actor(obs))
    before = {k: v.clone() for k, v in actor.state_dict().items()}
    critic_before = {k: v.clone() for k, v in critic.state_dict().items()}
    runner.learn(1)
    moved = {k for k, v in actor.state_dict().items() if not torch.equal(v, before[k])}
    assert moved == {k for k in before if k.startswith(("trunk.task_tokenizers.climb.", "adapter."))} \
        | {"distribution.std_param"}
    assert all(torch.equal(actor.state_dict()[k], before[k]) for k in before if k.startswith("obs_normalizer."))
    assert int(actor.obs_normalizer.count) == int(base.alg.actor.obs_normalizer.count) > 0
    critic_moved = {k for k, v in critic.state_dict().items() if not torch.equal(v, critic_before[k])}
    assert "obs_normalizer._mean" in critic_moved and any(k.startswith("mlp.") for k in critic_moved)


# ------------------------------------------------- a skill the previous stage never ran
def _carry_stage_from_follow(tmp_path: Path, *overrides: str):
    """A one-iteration TokenHSI Follow run, then the Carry stage's start from it (the protocol's
    `train.init_from` with merged statistics): (actor, first Carry observation, log line)."""
    from detach import cli
    from detach.runfolder.folder import find_runs
    from detach.train.setup import load_initial_weights
    assert cli.main(["train", str(ROOT / "configs/tasks/follow.yaml"), "--model", "tokenhsi", "--runs",
                     str(tmp_path), "--no-eval", *TINY, "train.max_iterations=1"]) == 0
    (run,) = find_runs(tmp_path)
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", "tokenhsi",
                      [*TINY, f"train.init_from={run.path}", "train.init_normalizers=merge", *overrides])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    line = load_initial_weights(runner, cfg)
    return runner.alg.actor, env.get_observations(), line


def _told_to_follow(obs: TensorDict) -> TensorDict:
    out = obs.clone()
    out["task"] = torch.zeros_like(obs["task"])
    out["task"][:, skill_names().index("follow")] = 1.0
    return out


def test_a_carry_stage_from_follow_starts_with_the_follow_policy_heading_for_the_box(tmp_path: Path) -> None:
    """Follow trains only the follow tokenizer (the mask hides the others), so a Carry stage
    started from it read Carry's frame through a random carry tokenizer: the behaviour Follow
    learned was out of reach (TokenHSI's laptop Carry cell 0.00 before and after training, where
    the other models' Follow policies walk to the box). With `tokenizer_from: {carry: follow}`
    the carry tokenizer starts as Follow's (path columns folded into the target's: outside a
    path every path point is the target's XY), so the stage starts with the actions the policy
    takes when told to follow, on the same Carry frame: to the box. The shipped model sets it."""
    actor, obs, _ = _carry_stage_from_follow(tmp_path / "plain", "model.tokenizer_from={}")
    assert bool(obs["task"][:, skill_names().index("carry")].all())
    with torch.no_grad():
        assert not torch.allclose(actor(obs), actor(_told_to_follow(obs)), atol=1e-3)  # the random tokenizer
    actor, obs, line = _carry_stage_from_follow(tmp_path / "copied")  # configs/models/tokenhsi.yaml
    assert "task tokenizers copied: carry <- follow" in line
    trunk = actor.trunk
    with torch.no_grad():
        torch.testing.assert_close(actor(obs), actor(_told_to_follow(obs)), atol=1e-4, rtol=1e-4)
        box = range(trunk.layout.spec.env_dim)[trunk.layout.spec.env_fields()["object"]]
        box_columns = [c for c, i in enumerate(trunk.carry_index.tolist()) if i in box]
        assert len(box_columns) == 33 and bool((trunk.task_tokenizers["carry"][0].weight[:, box_columns] == 0).all())
        # a skill the source ran keeps its own tokenizer (an LH1 stage from a Carry cell)
        before = {k: v.clone() for k, v in trunk.task_tokenizers["carry"].state_dict().items()}
        actor.obs_normalizer._mean[0, actor.layout.columns("task")[skill_names().index("carry"), 0]] = 0.3
        assert actor.start_from_loaded() == []
        assert all(torch.equal(v, before[k]) for k, v in trunk.task_tokenizers["carry"].state_dict().items())
