"""Training on the real env: every model runs PPO+AMP on the puppet, DETACH's stages behave."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach.config import resolve
from detach.train.setup import build_runner

ROOT = Path(__file__).resolve().parents[1]
MODELS = ["mlp", "tokenhsi", "cml", "detach", "ablation_a1", "ablation_a2"]
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=4",
        "train.num_mini_batches=2", "train.num_learning_epochs=1", "env.episode_length=40"]


@pytest.mark.parametrize("model", MODELS)
def test_three_iterations_of_each_model_write_a_checkpoint(model: str, tmp_path: Path) -> None:
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", model, [*TINY, "train.max_iterations=3"])
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    runner.checkpoint_dir = tmp_path
    seen: list[dict] = []
    runner.on_iteration = lambda _it, metrics: seen.append(metrics)
    runner.learn(3)
    assert len(seen) == 3 and all(torch.isfinite(torch.tensor(m["Perf/total_fps"])) for m in seen)
    assert "Loss/amp/accuracy" in seen[-1] or "Loss/amp_upper/accuracy" in seen[-1]
    saved = torch.load(tmp_path / "model_2.pt", weights_only=False)
    assert saved["iter"] == 2 and "discriminator_state_dict" in saved
    if model == "cml":
        assert runner.alg.num_objectives == 3  # task + upper-body + lower-body style
        assert runner.alg.storage.values.shape[-1] == 3


@pytest.mark.parametrize("task", ["carry", "climb", "sit", "lh1"])
def test_a_model_trains_on_every_kind_of_task(task: str) -> None:
    cfg = resolve(ROOT / f"configs/tasks/{task}.yaml", "mlp", [*TINY, "train.max_iterations=2"])
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    runner.learn(2)
    assert runner.completed_iteration == 1


def test_fusion_stage_leaves_encoders_bit_identical() -> None:
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "detach",
                  [*TINY, "train.max_iterations=4", "train.stages.pretrain=1",
                   "train.stages.fusion=2", "train.stages.joint=1"])
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    actor = runner.alg.actor
    snapshots: dict[str, dict[str, torch.Tensor]] = {}
    fusion_before = [p.detach().clone() for p in actor.fusion_parameters()]

    trainable: dict[str, bool] = {}

    def on_iteration(it: int, _metrics: dict) -> None:
        key = runner.alg.stage + str(it)
        snapshots[key] = {f"{i}": p.detach().clone()
                          for i, p in enumerate(actor.encoder_parameters())}
        trainable[key] = all(p.requires_grad for p in actor.encoder_parameters())

    runner.on_iteration = on_iteration
    runner.learn(4)
    after_pretrain, after_fusion = snapshots["pretrain0"], snapshots["fusion2"]
    assert all(torch.equal(after_pretrain[k], after_fusion[k]) for k in after_pretrain), \
        "stage 2 must not move the frozen encoders"
    assert any(not torch.equal(a, p) for a, p in zip(fusion_before, actor.fusion_parameters())), \
        "stage 2 trains the fusion layers"
    assert trainable == {"pretrain0": True, "fusion1": False, "fusion2": False, "joint3": True}


def test_shared_trunk_is_optimised_once_and_resumes(tmp_path: Path) -> None:
    """configs/models/detach.yaml: the critic reads the actor's trunk, the optimiser lists each
    parameter once (a duplicate would get two Adam steps per update), and a checkpoint
    restores trunk, value head and optimiser state."""
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "detach",
                  [*TINY, "train.max_iterations=2", "train.stages.pretrain=1"])
    assert cfg.model.shared_trunk
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    alg = runner.alg
    listed = [p for g in alg.optimizer.param_groups for p in g["params"]]
    assert len({id(p) for p in listed}) == len(listed)
    assert {id(p) for p in listed} == {id(p) for m in (alg.actor, alg.critic) for p in m.parameters()}
    assert not alg.critic.owns_trunk and alg.critic.head_groups == ("critic",)
    runner.checkpoint_dir = tmp_path
    runner.learn(2)
    _env2, resumed = build_runner(cfg, None, "cpu", progress=False)
    assert resumed.load_checkpoint(tmp_path / "model_1.pt") == 2
    obs = env.get_observations()
    with torch.no_grad():
        assert torch.equal(resumed.alg.critic(obs), alg.critic(obs))
        assert torch.equal(resumed.alg.actor(obs), alg.actor(obs))
    a, b = alg.optimizer.state_dict(), resumed.alg.optimizer.state_dict()
    assert a["state"].keys() == b["state"].keys()
    assert all(torch.equal(v, b["state"][k][name]) for k in a["state"] for name, v in a["state"][k].items())
