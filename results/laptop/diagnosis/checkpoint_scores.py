"""Score every checkpoint of run folders on validation and evaluation trials (CSV to stdout).

    python results/laptop/diagnosis/checkpoint_scores.py RUN_DIR [RUN_DIR ...] > scores.csv

Per checkpoint: the LH mean over 50 validation trials (the env seed the platform's choices use:
the run's seed + 7919) and over 100 trials of `detach-run eval` (its env, its seed). This is
how the drift of the Carry stage past its best checkpoint was found, which led to
`train.select_checkpoint_trials`.
"""

from __future__ import annotations

import csv
import sys
from pathlib import Path

import torch

from detach import (
    RunFolder, apply_torch_threads, checkpoint_iteration, load_policy, make_env, run_evaluation, seed_everything,
    validation_env, validation_score,
)


def main(run_dirs: list[str]) -> None:
    out = csv.writer(sys.stdout)
    out.writerow(["run", "checkpoint", "iteration", "validation_50", "evaluation_100"])
    for d in run_dirs:
        run = RunFolder(Path(d))
        cfg = run.config()
        apply_torch_threads(cfg)
        for path in reversed(run.checkpoint_files()):
            val_env = validation_env(cfg, 50, "cpu")
            actor, _ = load_policy(cfg, val_env, path, "cpu")
            val = validation_score(val_env, lambda obs: actor(obs), cfg, 50)
            seed_everything(cfg.seed + 1)  # as evaluate_run
            env = make_env(cfg, num_envs=min(cfg.eval.num_envs, 100), device="cpu", eval_mode=True, verbose=False)
            actor, _ = load_policy(cfg, env, path, "cpu")
            with torch.inference_mode():
                test = run_evaluation(env, lambda obs: actor(obs), 100, cfg, progress=False).lh_mean.rate
            out.writerow([run.path.name, path.name, checkpoint_iteration(path.name), f"{val:.3f}", f"{test:.3f}"])
            sys.stdout.flush()


if __name__ == "__main__":
    main(sys.argv[1:])
