"""`detach-run export --format init` and the shipped policy the README's first run starts from."""

from __future__ import annotations

import json
import os
from pathlib import Path

import pytest
import torch

from detach import cli
from detach.runfolder.folder import find_runs
from detach.train.run_config import resolve_run
from detach.train.setup import build_runner, load_initial_weights

ROOT = Path(__file__).resolve().parents[1]
SHIPPED = ROOT / "pretrained/puppet_follow_detach.init.pt"
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "eval.trials=2"]


def test_an_init_export_is_small_and_starts_a_run_with_the_same_policy(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(out), "--no-eval", *TINY,
                     "train.max_iterations=2"]) == 0
    (run,) = find_runs(out)
    target = tmp_path / "start.init.pt"
    assert cli.main(["export", str(run.path), "--format", "init", "--output", str(target)]) == 0
    info = json.loads((tmp_path / "start.init.json").read_text())
    assert info["format"] == "init" and info["model"] == "mlp" and info["check"]["max_abs_diff"] <= 0.05
    checkpoint = run.latest_checkpoint()
    assert target.stat().st_size < 0.6 * checkpoint.stat().st_size  # float16, no optimiser
    state = torch.load(target, weights_only=True)
    assert "optimizer_state_dict" not in state and "discriminator_state_dict" not in state
    halves = [k for k, v in state["actor_state_dict"].items() if v.dtype == torch.float16]
    assert halves and not any("normalizer" in k for k in halves)

    cfg = resolve_run(ROOT / "configs/tasks/follow.yaml", "mlp",
                      TINY + [f"train.init_from={target}", "train.init_normalizers=keep"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    line = load_initial_weights(runner, cfg)
    assert "model mlp (mlp)" in line, line  # named from the file, which has no run folder
    source = torch.load(checkpoint, weights_only=True)["actor_state_dict"]
    loaded = runner.alg.actor.state_dict()
    for k, v in source.items():
        torch.testing.assert_close(loaded[k].float(), v.float(), atol=2e-3, rtol=2e-3)


def test_the_first_run_preset_resolves_and_its_shipped_policy_fits_detach(monkeypatch: pytest.MonkeyPatch) -> None:
    assert SHIPPED.is_file() and SHIPPED.stat().st_size <= 10 * 2**20
    monkeypatch.chdir(ROOT)  # the preset names the file relative to the repository, as the README runs it
    cfg = resolve_run(ROOT / "configs/tasks/follow.yaml", "detach", ["sim.num_envs=2"],
                      presets=["first_run"])
    assert cfg.train.init_from and os.path.samefile(cfg.train.init_from, SHIPPED)
    assert cfg.train.learning_rate <= 1e-5 and cfg.env.character == "puppet"
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    assert "model detach (detach), iteration 399" in load_initial_weights(runner, cfg)
