"""Training presets (configs/presets/): TokenHSI's PPO settings and the paper's scale, merged
over task and model by `detach-run --preset`, recorded in config.yaml and used by training."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch
import yaml

from detach import cli
from detach.runfolder.folder import find_runs

ROOT = Path(__file__).resolve().parents[1]
FOLLOW = str(ROOT / "configs/tasks/follow.yaml")
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "train.max_iterations=2"]


def dry_run(capsys: pytest.CaptureFixture[str], *args: str) -> dict:
    capsys.readouterr()
    assert cli.main([FOLLOW, "--model", "tokenhsi", "--dry-run", *args]) == 0
    return yaml.safe_load(capsys.readouterr().out)


def test_presets_merge_in_order_and_overrides_win(capsys: pytest.CaptureFixture[str]) -> None:
    base = dry_run(capsys)
    cfg = dry_run(capsys, "--preset", "tokenhsi_ppo", "--preset", "paper", "train.max_iterations=7")
    t, m = cfg["train"], cfg["model"]
    assert (t["learning_rate"], t["schedule"], t["gamma"], t["lam"]) == (2e-5, "fixed", 0.99, 0.95)
    assert (t["num_steps_per_env"], t["num_learning_epochs"], t["num_mini_batches"]) == (32, 6, 8)
    assert (t["clip_param"], t["value_loss_coef"], t["max_grad_norm"], t["clipped_value_loss"]) == (
        0.2, 5.0, 1.0, False)
    assert math.isclose(math.log(m["init_noise_std"]), -2.9, abs_tol=1e-5) and m["learn_noise_std"] is False
    amp = t["amp"]
    assert (amp["task_reward_weight"], amp["style_reward_weight"], amp["objective"]) == (0.5, 1.0, "logistic")
    assert cfg["sim"]["num_envs"] == 4096 and cfg["eval"]["trials"] == 100
    assert t["max_iterations"] == 7, "command-line overrides come after presets"
    assert (t["num_mini_batches"] * 16384) == cfg["sim"]["num_envs"] * t["num_steps_per_env"]
    assert base["sim"]["num_envs"] < 4096 and base["model"]["learn_noise_std"] is True, "defaults stay laptop-sized"


def test_an_unknown_preset_or_key_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--preset", "papr", "--dry-run"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "papr" in err[0]
    bad = tmp_path / "bad.yaml"
    bad.write_text("train:\n  learning_rate: 1.0e-4\nscene: []\n")
    assert cli.main([FOLLOW, "--model", "mlp", "--preset", str(bad), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "bad.yaml:3" in err and "scene" in err


def test_a_fixed_action_std_stays_fixed_through_training(tmp_path: Path) -> None:
    assert cli.main([FOLLOW, "--model", "mlp", "--preset", "tokenhsi_ppo", "--out", str(tmp_path),
                     "--no-eval", *TINY]) == 0
    run = find_runs(tmp_path)[0]
    assert run.config().model.learn_noise_std is False
    actor = torch.load(run.latest_checkpoint(), weights_only=True)["actor_state_dict"]
    std = [v for k, v in actor.items() if k.startswith("distribution.")]
    assert std and all(torch.allclose(v, torch.full_like(v, math.exp(-2.9)), rtol=1e-5) for v in std)
