"""`detach-run`: resolve a task + model configuration and run it.

User errors (bad config, bad flag) print one line and exit with code 2; tracebacks are
reserved for bugs.
"""

from __future__ import annotations

import argparse
import sys
import time
from pathlib import Path
from typing import Sequence

from detach.config import ConfigError, dump, resolve
from detach.config_schema import RunConfig

EXIT_USAGE = 2

DESCRIPTION = """\
Run a task of the DETACH study with one model.

  detach-run configs/tasks/lh3.yaml --model ablation_a1 --dry-run
  detach-run configs/tasks/follow.yaml --model detach env.character=puppet train.max_iterations=50

TASK_YAML is a file under configs/tasks/ (follow, carry, climb, sit, lh1, lh2, lh3).
--model takes a name from configs/models/ (detach, ablation_a1, ablation_a2, tokenhsi, cml,
mlp) or a path to a model YAML. Overrides are key.path=value with YAML values, e.g.
sim.num_envs=16, scene[0].pos3d=[1,2,0.35]; +key.path=value adds a key that does not exist.
"""


def build_parser() -> argparse.ArgumentParser:
    parser = argparse.ArgumentParser(
        prog="detach-run", description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task", metavar="TASK_YAML", help="task configuration file")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides (YAML values); +key=value adds a new key")
    parser.add_argument("--model", default="detach",
                        help="model name in configs/models/ or a model YAML path "
                             "(default: detach)")
    parser.add_argument("--seed", type=int, default=0, help="random seed (default: 0)")
    parser.add_argument("--device", default="cpu",
                        help="torch device: cpu, cuda or cuda:N (default: cpu)")
    parser.add_argument("--out", type=Path, default=Path("runs"),
                        help="parent folder of run folders (default: runs/)")
    parser.add_argument("--dry-run", action="store_true",
                        help="resolve and print the config and the run folder it would "
                             "create, then exit")
    return parser


def run_folder_name(cfg: RunConfig, now: float | None = None) -> str:
    """runs/<YYYYmmdd-HHMMSS>-<task>-<model>-s<seed> (the run folder contract)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    return f"{stamp}-{cfg.task_name}-{cfg.model_name}-s{cfg.seed}"


def check_device(device: str) -> None:
    """Fail early, as a user error, on a device this machine does not have."""
    if device == "cpu":
        return
    if not (device == "cuda" or device.startswith("cuda:")):
        raise ConfigError(f"--device: expected cpu, cuda or cuda:N, found '{device}'")
    import torch

    if not torch.cuda.is_available():
        raise ConfigError(f"--device {device}: CUDA is not available on this machine "
                          f"(torch {torch.__version__}); use --device cpu")


def main(argv: Sequence[str] | None = None) -> int:
    parser = build_parser()
    args = parser.parse_intermixed_args(argv)
    try:
        if not Path(args.task).exists():
            raise ConfigError("task file not found", args.task)
        check_device(args.device)
        cfg = resolve(args.task, args.model, args.overrides, seed=args.seed,
                      device=args.device)
    except ConfigError as exc:
        print(f"detach-run: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    folder = args.out / run_folder_name(cfg)
    if args.dry_run:
        sys.stdout.write(dump(cfg))
        print(f"# run folder: {folder}")
        return 0
    print("detach-run: error: training is not available in this version yet; "
          "use --dry-run to check a configuration", file=sys.stderr)
    return EXIT_USAGE


if __name__ == "__main__":
    sys.exit(main())
