"""`detach-run export --format policy`: a shipped policy holds what acting reads and nothing
else (DETACH's pre-training heads and R1/R2 anchors are training-only), and evaluates as the
run it came from."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach import cli
from detach.envs.lh_env import make_env
from detach.runfolder.folder import RunFolder, find_runs
from detach.runs.policy import load_policy

TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "train.max_iterations=3", "train.stages.pretrain=1", "train.stages.fusion=1",
        "train.stages.joint=1", "train.torch_threads=1"]
TRAINING_ONLY = ("trunk.env_decoder.", "trunk.self_decoder.", "trunk.predictor.", "trunk.env_anchor.",
                 "trunk.self_anchor.")


@pytest.fixture(scope="module")
def detach_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    assert cli.main(["train", "follow", "--model", "detach", "--runs", str(out), "--no-eval", *TINY]) == 0
    (run,) = find_runs(out)
    return run.path


def test_a_detach_policy_ships_without_its_training_only_weights_and_plays_as_its_run(
        detach_run: Path, tmp_path: Path) -> None:
    policy = tmp_path / "follow_detach.policy.pt"
    assert cli.main(["export", str(detach_run), "--format", "policy", "--output", str(policy)]) == 0
    weights = torch.load(policy, weights_only=True)["actor_state_dict"]
    assert not [k for k in weights if k.startswith(TRAINING_ONLY)]
    assert any(k.startswith("trunk.env_encoder.") for k in weights)  # the encoders act, so they stay
    full = torch.load(sorted((detach_run / "checkpoints").glob("model_*.pt"))[-1], weights_only=True)
    dropped = sum(v.numel() for k, v in full["actor_state_dict"].items() if k.startswith(TRAINING_ONLY))
    kept = sum(v.numel() for v in weights.values())
    assert dropped > 0.2 * (kept + dropped)  # the point: a quarter of DETACH's actor never acts

    # what the file lacks never acts: two loads whose missing modules start from different
    # random weights give the same actions, within float16 of the run's own checkpoint
    run = RunFolder(detach_run)
    cfg = run.config()
    env = make_env(cfg, num_envs=4, device="cpu", eval_mode=True)
    obs = env.get_observations()
    actions = []
    for seed in (1, 2):
        torch.manual_seed(seed)
        actor, _state = load_policy(cfg, env, policy)
        with torch.no_grad():
            actions.append(actor(obs))
    torch.testing.assert_close(actions[0], actions[1], rtol=0, atol=0)
    actor, _state = load_policy(cfg, env, sorted(run.checkpoints.glob("model_*.pt"))[-1])
    with torch.no_grad():
        torch.testing.assert_close(actions[0], actor(obs), rtol=0, atol=0.05)


def test_a_policy_lacking_a_weight_that_acts_is_refused_in_one_line(
        detach_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    policy = tmp_path / "p.policy.pt"
    assert cli.main(["export", str(detach_run), "--format", "policy", "--output", str(policy)]) == 0
    state = torch.load(policy, weights_only=True)
    state["actor_state_dict"] = {k: v for k, v in state["actor_state_dict"].items()
                                 if not k.startswith("trunk.fusion.")}
    torch.save(state, policy)
    capsys.readouterr()
    assert cli.main(["eval", str(policy), "--task", "follow", "--trials", "2"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "p.policy.pt" in err[0] and "trunk.fusion" in err[0], err
