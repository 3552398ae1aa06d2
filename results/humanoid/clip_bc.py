"""Behaviour-clone a humanoid actor on the motion clips' own hinge targets: a start for PPO
(`detach.train.clip_clone`; its docstring says how).

    python results/humanoid/clip_bc.py RUN_OR_CONFIG OUT.pt [--rounds 60] [--steps 45]
        [--epochs 30] [--assist TORQUE DAMPING] [KEY=VALUE ...]

RUN_OR_CONFIG: a humanoid run folder (or its config.yaml) whose env and model to clone into;
`--assist` collects under the balance assist (`train.balance_assist`). Then train from it:
`detach-run train follow ... train.init_from=OUT.pt train.critic_warmup_iterations=20`.
"""

from __future__ import annotations

import argparse
from pathlib import Path

from detach import clone_clip_start, load_run_config


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", type=Path, help="a humanoid run folder or its config.yaml")
    ap.add_argument("out", type=Path)
    ap.add_argument("--rounds", type=int, default=60)
    ap.add_argument("--steps", type=int, default=45)
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--assist", type=float, nargs=2, default=(0.0, 0.0), metavar=("TORQUE", "DAMPING"))
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()
    path = args.config / "config.yaml" if args.config.is_dir() else args.config
    cfg = load_run_config(path, ["env.init=random", "train.max_iterations=1", *args.overrides])
    clone_clip_start(cfg, args.out, args.rounds, args.steps, args.epochs, tuple(args.assist))


if __name__ == "__main__":
    main()
