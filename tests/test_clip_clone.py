"""`clone_clip_start`: the actor fitted to the clips' open-loop hinge targets, written as a
checkpoint that `train.init_from` starts a humanoid run from."""

from __future__ import annotations

from pathlib import Path

import torch

from detach import build_runner, clone_clip_start, load_initial_weights, resolve

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["env.init=random", "sim.num_envs=8", "env.height_map.enabled=false", "train.max_iterations=1",
         "model.learn_noise_std=false", "model.init_noise_std=0.055"]


def test_the_clone_fits_the_clips_and_starts_a_run(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", SMALL)
    out = tmp_path / "clone.pt"
    lines: list[str] = []
    figures = clone_clip_start(cfg, out, rounds=2, steps=8, epochs=40, assist=(1000.0, 30.0), log=lines.append)
    assert out.is_file() and any(line.startswith("closed loop, assist 1000/30") for line in lines)
    assert 50 < figures["pairs"] <= 2 * 8 * 8
    assert figures["mse"] < 0.5 * figures["action_variance"], figures  # it learned the targets
    start = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", [*SMALL[1:], f"train.init_from={out}"])
    _env, runner = build_runner(start, None, "cpu", progress=False)
    assert "initialised from" in load_initial_weights(runner, start)
