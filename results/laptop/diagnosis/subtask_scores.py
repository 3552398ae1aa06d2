"""Each subtask's success rate of chosen checkpoints on the validation trials (stdout).

    python results/laptop/diagnosis/subtask_scores.py RUN_DIR ITERATION [ITERATION ...]

The LH mean a run's checkpoint choice prints hides which subtask failed; this plays the same 50
validation trials (the run's seed + 7919, as `train.select_checkpoint_trials` does) and prints
the rate of every subtask of the plan. It found that the taught LH1 runs of 2026-12-06 score 0
at some checkpoints because Follow stops at LH1's doorway, not because the later skills fail.
"""

from __future__ import annotations

import sys
from pathlib import Path

import torch

from detach import RunFolder, apply_torch_threads, load_policy, run_evaluation, validation_env, validation_seed

TRIALS = 50


def main(run_dir: str, iterations: list[int]) -> None:
    run = RunFolder(Path(run_dir))
    cfg = run.config()
    apply_torch_threads(cfg)
    env = validation_env(cfg, TRIALS, "cpu")
    print("iteration," + ",".join(s.skill for s in env.plan) + ",lh_mean")
    for it in iterations:
        actor, _ = load_policy(cfg, env, run.path / "checkpoints" / f"model_{it}.pt", "cpu")
        env.gen.manual_seed(validation_seed(cfg))
        with torch.inference_mode():
            env.reset()
            result = run_evaluation(env, lambda obs: actor(obs), TRIALS, cfg, progress=False)
        print(f"{it}," + ",".join(f"{s.rate:.2f}" for s in result.subtasks) + f",{result.lh_mean.rate:.3f}", flush=True)


if __name__ == "__main__":
    main(sys.argv[1], [int(a) for a in sys.argv[2:]])
