"""Train a tiny run

`detach-run train` as a function call (`detach.train_run`): a run folder (config.yaml,
status.json, log.mcap, checkpoints/, eval.json) under --runs. A few PPO iterations of the MLP on
the follow task with the puppet character take seconds on a CPU.

    python examples/05_train_tiny_run.py [--runs /tmp/detach-example-runs] [--iterations 2]
"""

import argparse
from pathlib import Path

from detach import RunFolder, train_run


def main(runs: Path, iterations: int) -> None:
    outcome = train_run("follow", "mlp", runs=runs, trials=2,
                        overrides=["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8",
                                   "eval.num_envs=2", "env.episode_length=60", f"train.max_iterations={iterations}"])
    assert outcome.code == 0, outcome
    run = RunFolder(outcome.run)
    result = run.eval_result()
    print(f"{run.path}: {run.status().state}, follow success {result.subtasks[0].rate:.2f} over {result.trials} "
          f"trials; next: detach-run play {run.path}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=Path, default=Path("/tmp/detach-example-runs"))
    parser.add_argument("--iterations", type=int, default=2)
    args = parser.parse_args()
    main(args.runs, args.iterations)
