"""Validation trials: what a run scores itself on when it chooses (a start, a checkpoint).

A choice made on the evaluation's own trials would report the best of several draws as if it
were one. So a run's choices play trials of its task in an env of another seed (the run's
plus `VALIDATION_SEED_OFFSET`), every candidate the same trials, and the evaluation stays a
fresh sample.
"""

from __future__ import annotations

from typing import Callable

import torch

from detach.config_schema import RunConfig
from detach.envs.lh_env import LHEnv, make_env
from detach.eval.episodes import run_evaluation

VALIDATION_SEED_OFFSET = 7919
"""The validation env's seed is the run's plus this: its trials are not the evaluation's
(whose env takes the run's seed)."""


def validation_seed(cfg: RunConfig) -> int:
    return int(cfg.seed) + VALIDATION_SEED_OFFSET


def validation_env(cfg: RunConfig, trials: int, device: str) -> LHEnv:
    """An evaluation env of the run's task on the validation seed."""
    return make_env(cfg, num_envs=min(cfg.eval.num_envs, trials), device=device, eval_mode=True, verbose=False,
                    seed=validation_seed(cfg))


def validation_score(env: LHEnv, policy: Callable[[object], torch.Tensor], cfg: RunConfig, trials: int) -> float:
    """LH mean of `policy` (mean actions) over `trials` validation trials; every call on the
    same env plays the same trials."""
    env.gen.manual_seed(validation_seed(cfg))
    with torch.inference_mode():  # the env's tensors are inference tensors from the first trial on
        env.reset()
        result = run_evaluation(env, policy, trials, cfg, progress=False)
    return float(result.lh_mean.rate)
