"""DETACH's stage 2 with its frozen encoders run once per update (`train.reuse_frozen_features`)
is the same training as running them in every mini-batch: equal statistics and parameters."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach.config import resolve
from detach.train.setup import build_runner

TASKS = Path(__file__).resolve().parents[1] / "configs" / "tasks"


class Metrics:
    def __init__(self) -> None:
        self.rows: list[dict[str, float]] = []

    def log_metrics(self, iteration: int, metrics: dict[str, float], stage: str = "") -> None:
        self.rows.append({"iteration": iteration, "stage": stage, **metrics})


def _train(reuse: bool, model: str = "detach", iterations: int = 4):
    cfg = resolve(TASKS / "follow.yaml", model, [
        "env.character=puppet", "sim.num_envs=8", "sim.nthread=1", "train.num_steps_per_env=8",
        "train.stages.pretrain=1", "train.stages.fusion=100", "train.torch_threads=1",
        f"train.reuse_frozen_features={str(reuse).lower()}"])
    sink = Metrics()
    _env, runner = build_runner(cfg, None, "cpu", log=sink, progress=False)
    seen = []
    features = runner.alg.actor.frozen_features

    def counted(obs):
        out = features(obs)
        if out is not None:
            seen.append(obs.batch_size[0])
        return out

    runner.alg.actor.frozen_features = counted
    runner.learn(iterations)
    return sink.rows, runner.alg.actor.state_dict(), seen


@pytest.mark.parametrize("model", ["detach", "ablation_a1"])
def test_frozen_encoders_run_once_per_update_with_the_same_statistics(model):
    rows, params, seen = _train(True, model)
    before_rows, before_params, before_seen = _train(False, model)
    stages = [r["stage"] for r in rows]
    assert stages.count("fusion") == 2 and stages[0] == "pretrain"
    # each stage-2 update: before PPO's epochs, and again before the auxiliary pass (PPO's
    # update ends by moving the input normalisers), each time over the whole rollout
    assert seen == [64] * 4 and before_seen == []
    for new, old in zip(rows, before_rows, strict=True):
        keys = sorted(k for k in old if isinstance(old[k], float) and not k.startswith("Perf/"))
        assert keys and keys == sorted(k for k in new if isinstance(new[k], float) and not k.startswith("Perf/"))
        for k in keys:
            assert new[k] == pytest.approx(old[k], rel=1e-4, abs=1e-6), (new["iteration"], k)
    for name, value in before_params.items():
        torch.testing.assert_close(params[name], value, rtol=1e-4, atol=1e-6, msg=name)
