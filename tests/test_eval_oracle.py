"""The evaluation code path of `detach-run --eval`, driven by the scripted oracle: it must
report near-perfect LH success, and a random policy must report failure."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.envs.oracle import Oracle, random_policy
from detach.eval.episodes import run_evaluation

ROOT = Path(__file__).resolve().parents[1]


@pytest.mark.parametrize("task", ["lh1", "lh2", "lh3"])
def test_oracle_through_the_evaluator(task: str) -> None:
    torch.set_num_threads(1)
    cfg = resolve(ROOT / f"configs/tasks/{task}.yaml", "mlp", ["env.character=puppet"], seed=1)
    env = make_env(cfg, num_envs=6, eval_mode=True, verbose=False)
    oracle = Oracle(env)
    result = run_evaluation(env, lambda _obs: oracle(), trials=6, cfg=cfg, progress=False)
    assert result.trials == 6
    assert result.lh_success.rate >= 0.95, result
    assert all(s.rate == 1.0 for s in result.subtasks)
    assert 5.0 < result.mean_execution_time < 40.0


def test_random_policy_through_the_evaluator() -> None:
    torch.set_num_threads(1)
    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "mlp",
                  ["env.character=puppet", "env.episode_length=300"], seed=1)
    env = make_env(cfg, num_envs=6, eval_mode=True, verbose=False)
    policy = random_policy(env, torch.Generator().manual_seed(0))
    result = run_evaluation(env, lambda obs: policy(obs), trials=6, cfg=cfg, progress=False)
    assert result.lh_success.rate == 0.0
