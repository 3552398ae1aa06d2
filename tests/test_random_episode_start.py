"""`train.init_at_random_ep_len`: training starts each environment at a random step of its
first episode, so that episodes do not all end at the same iteration (Carry learned nothing
with every batch drawn from one phase of 64 synchronised 1200-step episodes)."""

from __future__ import annotations

from pathlib import Path

import pytest

from detach import cli
from detach.train.run_config import resolve_run
from detach.train.runner import DetachRunner
from detach.train.setup import build_runner

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.character=puppet", "sim.num_envs=8", "train.num_steps_per_env=4", "env.episode_length=600",
        "train.max_iterations=1"]


@pytest.mark.parametrize("spread", [True, False])
def test_episodes_start_spread_over_their_length_unless_switched_off(spread: bool) -> None:
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", "mlp",
                      TINY + [f"train.init_at_random_ep_len={str(spread).lower()}"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    runner.learn(cfg.train.max_iterations, init_at_random_ep_len=cfg.train.init_at_random_ep_len)
    steps = env.episode_length_buf.tolist()
    assert (len(set(steps)) > 4) == spread, steps
    assert max(steps) < 600


def test_a_training_run_passes_the_setting_to_the_runner(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    seen = []
    monkeypatch.setattr(DetachRunner, "learn", lambda self, n, init_at_random_ep_len=False: seen.append(
        init_at_random_ep_len))
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(tmp_path), "--no-eval", *TINY]) == 0
    assert seen == [True]  # the default


def test_a_resumed_run_spreads_its_fresh_episodes_too(tmp_path: Path) -> None:
    """A resumed run rebuilds its environments, all at step 0: unspread, every batch of the
    resumed run came from one phase of synchronised episodes again (a resumed Carry run's
    curves fell at the resume point and its episodes all ran to the limit together)."""
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", "mlp", TINY)
    _env, first = build_runner(cfg, tmp_path, "cpu", progress=False)
    first.learn(1, init_at_random_ep_len=True)
    (checkpoint,) = tmp_path.glob("model_*.pt")
    env, runner = build_runner(cfg, tmp_path, "cpu", progress=False)
    assert runner.load_checkpoint(checkpoint) == 1
    runner.learn(2, init_at_random_ep_len=True)
    steps = env.episode_length_buf.tolist()
    assert len(set(steps)) > 4 and max(steps) < 600, steps
