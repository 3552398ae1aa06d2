"""What an evaluation leaves for the replay (issue 22 item 10): every counted trial of every
env recorded as an episode of its own, (checkpoint iteration, trial), each from its frame 0,
and the dashboard's reader lists and loads them all."""

from __future__ import annotations

from pathlib import Path

import numpy as np
import torch

from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.envs.oracle import random_policy
from detach.eval.episodes import run_evaluation
from detach.runs.mcap_log import RunLogWriter
from detach.runfolder.log_tail import LogTail
from server.episode import load_episode

ROOT = Path(__file__).resolve().parents[1]


def test_an_evaluation_records_every_trial_of_every_env(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp",
                  ["env.character=puppet", "env.episode_length=30"], seed=2)
    env = make_env(cfg, num_envs=2, eval_mode=True, verbose=False)
    policy = random_policy(env, torch.Generator().manual_seed(0))
    path = tmp_path / "log.mcap"
    with RunLogWriter(path, flush_every=7) as log:
        result = run_evaluation(env, lambda obs: policy(obs), trials=4, cfg=cfg, progress=False,
                                recorder=log, episode_id=12)
    assert result.trials == 4
    tail = LogTail(path)
    tail.refresh()
    assert tail.episode_keys() == [(12, t) for t in range(4)], "one episode per trial"
    lengths = []
    for key in tail.episode_keys():
        ep = load_episode(tail, key)
        assert ep.pos.shape[1:] == (15, 3) and np.isfinite(ep.pos).all()
        np.testing.assert_allclose(np.diff(ep.times), env.dt, rtol=1e-6)  # from frame 0, no gap
        lengths.append(ep.num_frames)
    assert all(2 <= n <= 31 for n in lengths), lengths
    ends = {tuple(np.round(load_episode(tail, k).pos[-1, 0, :2], 3)) for k in tail.episode_keys()}
    assert len(ends) > 1, "the trials are different episodes, not copies of one"


def test_training_records_env_0s_next_whole_episode_after_each_checkpoint(tmp_path: Path) -> None:
    """Item 10's training episodes: after checkpoint N, env 0's next episode from its frame 0
    to its end is (N, training); nothing is recorded between one and the next checkpoint."""
    from detach.eval.episodes import TRAINING_TRIAL, TrainingEpisodes
    from server.replay_panel import episode_options

    torch.set_num_threads(1)
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp",
                  ["env.character=puppet", "env.episode_length=12"], seed=3)
    env = make_env(cfg, num_envs=2, verbose=False)
    policy = random_policy(env, torch.Generator().manual_seed(1))
    path = tmp_path / "log.mcap"
    ends = []
    with RunLogWriter(path, flush_every=5) as log:
        recorder = TrainingEpisodes(log)
        obs = env.get_observations()
        with torch.inference_mode():
            for step in range(90):
                if step in (3, 50):  # checkpoints 7 and 19 were saved
                    recorder.start(7 if step == 3 else 19)
                if step == 10:
                    recorder.start(8)  # a checkpoint while recording: one episode at a time
                obs, _r, dones, _e = env.step(policy(obs))
                recorder.after_step(env, dones)
                if bool(dones[0]):
                    ends.append(step)
    tail = LogTail(path)
    tail.refresh()
    assert tail.episode_keys() == [(7, TRAINING_TRIAL), (19, TRAINING_TRIAL)]
    for key, after in ((7, 3), (19, 50)):
        ep = load_episode(tail, (key, TRAINING_TRIAL))
        start = min(e for e in ends if e > after)  # env 0's first reset after the checkpoint
        end = min(e for e in ends if e > start)
        assert ep.num_frames == end - start, (key, ep.num_frames, start, end)
        np.testing.assert_allclose(ep.times, np.arange(ep.num_frames) * env.dt, rtol=1e-6)
    assert episode_options(tail.episode_keys()) == {"7 · training": (7, -1),
                                                    "19 · training": (19, -1)}
