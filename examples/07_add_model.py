"""Add a model

A model kind is one module, `examples/linear_model.py` (its config class, trunk and rsl-rl model,
registered with `register_model` together with its table label), and a model YAML,
`examples/linear.yaml`, whose `kind: linear_model:LinearCfg` imports that module wherever the
run is loaded (the module must be importable: here examples/ is on the path; an installed
add-on names it in the `detach.model_kinds` entry points instead). Here it trains on the follow
task with the puppet and is evaluated, through the functions under the command line.

    python examples/07_add_model.py [--runs /tmp/detach-example-runs] [--iterations 2]
"""

import argparse
from pathlib import Path

from detach import RunFolder, evaluate, skills_table, train_run

HERE = Path(__file__).resolve().parent


def main(runs: Path, iterations: int) -> None:
    outcome = train_run("follow", str(HERE / "linear.yaml"), runs=runs, evaluate=False,
                        overrides=["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8",
                                   "eval.num_envs=2", "env.episode_length=60", f"train.max_iterations={iterations}"])
    assert outcome.code == 0, outcome
    run = RunFolder(outcome.run)
    evaluate(run.path, trials=2)
    row = skills_table([run.eval_result()], task="follow").rows[0]
    print(f"{run.path}: model {row[0]!r}, follow success {row[1].value:.2f}")


if __name__ == "__main__":
    parser = argparse.ArgumentParser()
    parser.add_argument("--runs", type=Path, default=Path("/tmp/detach-example-runs"))
    parser.add_argument("--iterations", type=int, default=2)
    args = parser.parse_args()
    main(args.runs, args.iterations)
