"""Train a tiny run

`detach-run train` as a function call: a run folder (config.yaml, status.json, log.mcap,
checkpoints/, eval.json) under --runs. A few PPO iterations of the MLP on the follow task with
the puppet character take seconds on a CPU.

    python examples/05_train_tiny_run.py [--runs /tmp/detach-example-runs] [--iterations 2]
"""

import argparse
from pathlib import Path

from detach import cli
from detach.runfolder.folder import find_runs


def main(runs: Path, iterations: int) -> None:
    code = cli.main(["train", "follow", "--model", "mlp", "--runs", str(runs), "--trials", "2",
                     "env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
                     "env.episode_length=60", f"train.max_iterations={iterations}"])
    assert code == 0, code
    run = find_runs(runs)[-1]
    result = run.eval_result()
    print(f"{run.path}: {run.status().state}, follow success {result.subtasks[0].rate:.2f} over {result.trials} "
          f"trials; next: detach-run play {run.path}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=Path, default=Path("/tmp/detach-example-runs"))
    parser.add_argument("--iterations", type=int, default=2)
    args = parser.parse_args()
    main(args.runs, args.iterations)
