"""Validation trials: what a run scores itself on when it chooses (a start, a checkpoint).

A choice made on the evaluation's own trials would report the best of several draws as if it
were one. So a run's choices play trials of its task in an env of another seed (the run's
plus `VALIDATION_SEED_OFFSET`), every candidate the same trials, and the evaluation stays a
fresh sample.
"""

from __future__ import annotations

from typing import Callable

import torch

from detach.config.schema import RunConfig
from detach.envs.lh_env import LHEnv, make_env
from detach.eval.episodes import run_evaluation
from detach.eval.trial_sets import VALIDATION_SEED_OFFSET, trial_seed

__all__ = ["VALIDATION_SEED_OFFSET", "validation_env", "validation_score", "validation_seed"]


def validation_seed(cfg: RunConfig) -> int:
    """The validation set's env seed (`detach.eval.trial_sets`): neither the development
    trials nor the test trials."""
    return trial_seed(cfg.seed, "validation")


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
