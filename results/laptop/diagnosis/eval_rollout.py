"""Shared by the Carry probes (`carry_approach.py`, `carry_after_grasp.py`, `carry_rollout.py`):
the evaluation's environment for a run's config, with a checkpoint's mean-action policy, and
quartiles for their one-line reports."""
from pathlib import Path

import torch

from detach import RunFolder, eval_config, load_policy, make_env, seed_everything


def eval_env_and_policy(run_dir: str, checkpoint: str, envs: int):
    """(run, cfg, env, actor): `envs` evaluation-mode environments (the evaluation's default
    starts, seed 1) and the checkpoint's policy."""
    run = RunFolder(Path(run_dir))
    cfg = eval_config(run.config(), None)
    seed_everything(1)
    env = make_env(cfg, num_envs=envs, device="cpu", eval_mode=True)
    actor, _ = load_policy(cfg, env, Path(checkpoint))
    return run, cfg, env, actor


def quartiles(x: torch.Tensor) -> str:
    return " / ".join(f"{v:.2f}" for v in torch.quantile(x, torch.tensor([0.25, 0.5, 0.75])).tolist())
