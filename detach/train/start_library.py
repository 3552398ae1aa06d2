"""The library of later-subtask starts (`env.subtask_start_prob`), recorded for a training env.

The states come from a second, small env of the same task that the scripted oracle drives
through one episode per env (`detach.envs.subtask_starts`). The train layer records them and
hands them to the training env (`make_env(..., subtask_starts=...)`), as it hands it the
motion library's reference states (`set_reference_sampler`): an env never builds another env.
"""

from __future__ import annotations

import time
from dataclasses import replace

import torch

from detach.character import character_class
from detach.config.schema import RunConfig
from detach.envs.lh_env import LHEnv, make_env
from detach.envs.subtask_starts import RECORD_ENVS, SubtaskStarts, recording_summary, record_subtask_starts


def record_start_library(cfg: RunConfig, device: str | torch.device = "cpu", assets: dict | None = None,
                         assets_root=None, verbose: bool = True) -> SubtaskStarts:
    """The oracle's states at the beginning of cfg's later subtasks (empty when it began none);
    ValueError where the task has one subtask or the oracle cannot drive the character. The
    recording env is seeded `cfg.seed + 1`, whatever the training env's seed."""
    prob = cfg.env.subtask_start_prob
    if len(cfg.task.plan) < 2:
        raise ValueError(f"env.subtask_start_prob: {prob} starts episodes at later subtasks, but task "
                         f"'{cfg.task.name}' has one subtask")
    if not character_class(cfg.env.character).scriptable:
        raise ValueError(f"env.subtask_start_prob: {prob} needs the scripted oracle, which cannot drive "
                         f"character '{cfg.env.character}'; use env.character=puppet or 0")
    quiet = replace(cfg, env=replace(cfg.env, subtask_start_prob=0.0, mid_task_init_prob=0.0))
    t0 = time.perf_counter()
    starts = record_subtask_starts(make_env(quiet, num_envs=RECORD_ENVS, device=device, assets=assets,
                                            assets_root=assets_root, verbose=False, seed=int(cfg.seed) + 1))
    if verbose or len(starts) == 0:
        print(recording_summary(starts, len(cfg.task.plan), time.perf_counter() - t0)
              + ("; no episode starts at a later subtask" if len(starts) == 0 else ""), flush=True)
    if len(starts):
        _ = starts.by_subtask  # built here: it reads the device, which a step's `draw` must not
    return starts


def make_training_env(cfg: RunConfig, num_envs: int | None = None, device: str | torch.device = "cpu",
                      seed: int | None = None, verbose: bool = True, assets: dict | None = None,
                      assets_root=None) -> LHEnv:
    """A training env of cfg, with the later-subtask starts recorded for it where
    `env.subtask_start_prob` > 0."""
    starts = record_start_library(cfg, device, assets, assets_root, verbose) \
        if cfg.env.subtask_start_prob > 0 else None
    return make_env(cfg, num_envs=num_envs, device=device, verbose=verbose, seed=seed, assets=assets,
                    assets_root=assets_root, subtask_starts=starts)
