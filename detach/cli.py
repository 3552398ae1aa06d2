"""`detach-run`: train, evaluate, resume and sweep runs; list runs; print the paper's tables.

User errors (bad config, bad flag, missing file) print one line and exit with code 2;
tracebacks are reserved for bugs (and go to the run's stdout.log).
"""

from __future__ import annotations

import argparse
import signal
import sys
import threading
import time
import typing
from pathlib import Path
from typing import Callable, Sequence

from detach.config import ConfigError, dump, resolve
from detach.config_schema import RunConfig
from detach.runs.folder import RunFolder, run_folder_name

EXIT_USAGE = 2

DESCRIPTION = """\
Run the DETACH study: train a model on a task, evaluate it, resume it, sweep a grid.

  detach-run configs/tasks/lh1.yaml --model detach            train, then evaluate
  detach-run configs/tasks/lh3.yaml --model ablation_a1 --dry-run
  detach-run configs/tasks/follow.yaml --model mlp env.character=puppet train.max_iterations=50
  detach-run --resume runs/20261123-120000-lh1-detach-s0 [train.max_iterations=2000] [--dry-run]
  detach-run --eval runs/20261123-120000-lh1-detach-s0 --task configs/tasks/lh2.yaml
  detach-run --sweep configs/sweeps/table3_ablation.yaml --quick --jobs 2
  detach-run list                                             table of runs
  detach-run table configs/sweeps/table1.yaml                 the paper's table from eval.json files

TASK_YAML is a file under configs/tasks/ (follow, carry, climb, sit, lh1, lh2, lh3).
--model takes a name from configs/models/ (detach, ablation_a1, ablation_a2, tokenhsi, cml,
mlp) or a path to a model YAML. Overrides are key.path=value with YAML values, e.g.
sim.num_envs=16, scene[0].pos3d=[1,2,0.35]; +key.path=value adds a key that does not exist.
Every run is a folder runs/<YYYYmmdd-HHMMSS>-<task>-<model>-s<seed>/ with config.yaml,
status.json, stdout.log, log.mcap, checkpoints/ and eval.json.
"""


class _Parser(argparse.ArgumentParser):
    """argparse, but a bad argument is one `ConfigError` line (exit code 2), not usage + error."""

    def error(self, message: str) -> typing.NoReturn:
        raise ConfigError(f"{message} (see {self.prog} --help)")


def _int_in(low: int, high: int | None = None) -> Callable[[str], int]:
    """argparse type: an integer in [low, high], named in the error."""
    def parse(text: str) -> int:
        try:
            value = int(text)
        except ValueError:
            raise argparse.ArgumentTypeError(f"expected an integer, found '{text}'") from None
        if value < low or (high is not None and value > high):
            bound = f">= {low}" if high is None else f"in [{low}, {high}]"
            raise argparse.ArgumentTypeError(f"expected an integer {bound}, found {value}")
        return value
    parse.__name__ = "integer"
    return parse


MAX_SEED = 2**32 - 1
"""NumPy's seeds are 32-bit."""


def build_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="detach-run", description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("task", metavar="TASK_YAML", nargs="?",
                        help="task configuration file (not with --resume/--eval/--sweep)")
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides (YAML values); +key=value adds a new key")
    parser.add_argument("--preset", action="append", default=[], metavar="NAME",
                        help="merge configs/presets/NAME.yaml (or a path) over task and model, before "
                             "the overrides; repeatable (e.g. paper, tokenhsi_ppo). With --sweep: one "
                             "of the sweep's presets (e.g. quick, laptop)")
    parser.add_argument("--model", default="detach",
                        help="model name in configs/models/ or a model YAML path "
                             "(default: detach)")
    parser.add_argument("--seed", type=_int_in(0, MAX_SEED), default=0,
                        help="random seed, 0 to 2^32-1 (default: 0)")
    parser.add_argument("--device", default="cpu",
                        help="torch device: cpu, cuda or cuda:N (default: cpu)")
    parser.add_argument("--out", type=Path, default=Path("runs"),
                        help="parent folder of run folders (default: runs/)")
    parser.add_argument("--dry-run", action="store_true",
                        help="resolve and print the config and the run folder it would "
                             "create, then exit (with --resume: the config it would continue with)")
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--resume", type=Path, metavar="RUN_DIR",
                      help="continue an interrupted or failed run from its latest checkpoint")
    mode.add_argument("--eval", type=Path, metavar="RUN_DIR|CKPT",
                      help="evaluate a run's latest checkpoint (or the given checkpoint)")
    mode.add_argument("--sweep", type=Path, metavar="SWEEP_YAML",
                      help="run every unfinished cell of a sweep (configs/sweeps/)")
    parser.add_argument("--task", dest="eval_task", type=Path, metavar="TASK_YAML",
                        help="with --eval: the task to evaluate on (default: the run's task); "
                             "a policy trained on LH1 evaluated on LH2/LH3 is the paper's "
                             "environment-generalisation experiment")
    parser.add_argument("--eval-on", action="append", type=Path, default=[],
                        metavar="TASK_YAML",
                        help="after training, also evaluate on this task (repeatable)")
    parser.add_argument("--trials", type=_int_in(1), default=None,
                        help="evaluation episodes (default: eval.trials of the config, 100)")
    parser.add_argument("--no-eval", action="store_true",
                        help="train only; skip the evaluation at the end")
    parser.add_argument("--quick", action="store_true",
                        help="with --sweep: use the sweep's quick preset (CPU smoke run)")
    parser.add_argument("--jobs", type=_int_in(1), default=1,
                        help="with --sweep: cells run in parallel (default: 1)")
    parser.add_argument("--models", default=None, metavar="A,B",
                        help="with --sweep: run only these of the sweep's models (their cells are "
                             "the same as in the whole sweep, so a later full run skips them)")
    parser.add_argument("--launcher", choices=["local", "ray", "slurm"], default="local",
                        help="with --sweep: a local worker pool, Ray tasks (the cluster of "
                             "RAY_ADDRESS, else a local Ray; the [ray] extra) or SLURM jobs through "
                             "submitit (the [slurm] extra; DETACH_SUBMITIT holds the job parameters "
                             "as JSON, docs/PROTOCOL.md)")
    parser.add_argument("--cell", help=argparse.SUPPRESS)
    return parser


def build_list_parser() -> argparse.ArgumentParser:
    parser = _Parser(prog="detach-run list",
                                     description="Print a table of the runs in a folder.")
    parser.add_argument("runs", type=Path, nargs="?", default=Path("runs"),
                        help="runs folder (default: runs/)")
    return parser


def build_table_parser() -> argparse.ArgumentParser:
    parser = _Parser(
        prog="detach-run table",
        description="Print the paper's table (Markdown) from eval.json files and write CSV "
                    "and LaTeX beside it.")
    parser.add_argument("source", type=Path, metavar="SWEEP_OR_RUNS",
                        help="a sweep YAML (its table kind and cells) or a runs folder")
    parser.add_argument("--runs", type=Path, default=Path("runs"),
                        help="runs folder holding a sweep's cells (default: runs/)")
    parser.add_argument("--kind", choices=["skills", "generalization", "ablation"],
                        help="table layout (default: the sweep's, or all three for a folder)")
    parser.add_argument("--out", type=Path, default=None,
                        help="folder for the .md/.csv/.tex files (default: <runs>/tables/)")
    parser.add_argument("--task", default=None,
                        help="evaluation task to tabulate instead of the paper's (LH1 for "
                             "skills, LH2 and LH3 for generalization, LH3 for ablation)")
    parser.add_argument("--sgr", choices=["reported", "formula"], default="reported",
                        help="skill generalisation rate: 'reported' reproduces the paper's values "
                             "(mean of the novel skills present over S_follow + S_carry), 'formula' "
                             "is its printed formula (docs/PROTOCOL.md)")
    which = parser.add_mutually_exclusive_group()
    which.add_argument("--preset", default=None, metavar="NAME",
                       help="with a sweep: the cells of this sweep preset (as run with --sweep --preset)")
    which.add_argument("--quick", action="store_true", help="with a sweep: the cells of its quick preset")
    return parser


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


def _fail(exc: Exception) -> int:
    print(f"detach-run: error: {exc}", file=sys.stderr)
    return EXIT_USAGE


EXIT_INTERRUPTED = 130


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; SIGTERM anywhere (start-up included) ends it like Ctrl-C: exit 130."""
    if threading.current_thread() is not threading.main_thread():
        return _main(argv)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        return _main(argv)
    except KeyboardInterrupt as exc:
        print(f"detach-run: interrupted ({str(exc) or 'SIGINT'})", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, previous)


def _main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        if argv and argv[0] == "list":
            from detach.runs.listing import print_runs

            return print_runs(build_list_parser().parse_args(argv[1:]).runs)
        if argv and argv[0] == "table":
            from detach.runs.tables_cli import print_table

            args = build_table_parser().parse_args(argv[1:])
            return print_table(args.source, args.runs, args.kind, args.out, args.task, args.sgr,
                               "quick" if args.quick else args.preset)
        args = build_parser().parse_intermixed_args(argv)
        if (args.resume or args.eval or args.sweep) and args.task:
            # No TASK_YAML in these modes: a positional key=value is an override.
            args.overrides, args.task = [args.task, *args.overrides], None
        check_device(args.device)
        if args.sweep:
            from detach.runs.sweep import run_sweep

            if len(args.preset) > 1:
                raise ConfigError("--sweep takes one --preset (one of the sweep's presets)")
            failed = run_sweep(args.sweep, args.out, args.jobs, args.quick, args.device,
                               launcher=args.launcher, preset=next(iter(args.preset), None),
                               models=args.models.split(",") if args.models else None)
            return 1 if failed else 0
        if args.resume:
            return _resume(args)
        if args.eval:
            return _evaluate(args)
        return _train(args)
    except ConfigError as exc:
        return _fail(exc)


def _train(args: argparse.Namespace) -> int:
    if args.task is None:
        raise ConfigError("missing TASK_YAML (or use --resume, --eval, --sweep, list, table)")
    if not Path(args.task).exists():
        raise ConfigError("task file not found", args.task)
    for extra in args.eval_on:
        if not extra.exists():
            raise ConfigError("task file not found (--eval-on)", str(extra))
    from detach.train.checks import complete_run_config

    cfg = complete_run_config(resolve(args.task, args.model, args.overrides, seed=args.seed, device=args.device,
                                      presets=args.preset))
    if args.dry_run:
        sys.stdout.write(dump(cfg))
        print(f"# run folder: {args.out / run_folder_name(cfg)}")
        return 0
    from detach.train.distributed import is_worker

    if is_worker():  # torchrun rank > 0: trains in step with rank 0, which alone writes the run folder
        from detach.train.setup import train_worker

        train_worker(cfg)
        return 0
    from detach.runs.job import run_job
    from detach.runs.session import train_and_evaluate

    try:
        run = RunFolder.create(args.out, cfg)
        if args.cell:
            run.set_state("queued", cell=args.cell)
    except OSError as exc:
        raise ConfigError(f"cannot create a run folder under --out {args.out} "
                          f"({exc.strerror or exc}); expected a writable folder") from None
    print(f"run folder: {run.path}")
    code = run_job(run, lambda r: train_and_evaluate(
        r, resume=False, eval_tasks=args.eval_on, trials=args.trials, evaluate=not args.no_eval))
    print(f"run folder: {run.path}")
    return code


def _resume(args: argparse.Namespace) -> int:
    run = RunFolder(args.resume)
    if not run.config_path.exists():
        raise ConfigError("not a run folder (no config.yaml)", str(args.resume))
    if run.latest_checkpoint() is None:
        raise ConfigError("run has no checkpoint to resume from", str(args.resume))
    _refuse_if_alive(run)
    cfg = run.config()  # validates the stored config as a user error, not a traceback
    checkpoint = _resume_checkpoint(run, cfg, rename=not args.dry_run)
    new = _extended_config(run, args.overrides, checkpoint) if args.overrides else cfg
    if args.dry_run:
        sys.stdout.write(dump(new))
        print(f"# would resume {run.path} from {checkpoint.name}")
        return 0
    if args.overrides:
        from detach.runs.folder import atomic_write_text

        atomic_write_text(run.config_path, dump(new))
    from detach.runs.job import run_job
    from detach.runs.session import train_and_evaluate

    print(f"resuming {run.path} from {checkpoint.name}")
    return run_job(run, lambda r: train_and_evaluate(
        r, resume=True, eval_tasks=args.eval_on, trials=args.trials, evaluate=not args.no_eval,
        device=args.device, checkpoint=checkpoint))


def _resume_checkpoint(run: RunFolder, cfg: RunConfig, rename: bool = True) -> Path:
    """The newest checkpoint that reads back whole and is of the run's model. Newer files that
    do not read back (truncated, corrupt) are renamed *.corrupt: the resumed run writes
    those iterations again, and no reader should pick the broken file meanwhile."""
    from detach.train.checkpoints import check_model, read_checkpoint

    checkpoint = run.usable_checkpoint()
    if checkpoint is None:
        raise ConfigError("no checkpoint of the run reads back whole (all truncated or corrupt)",
                          str(run.checkpoints))
    check_model(read_checkpoint(checkpoint), checkpoint, cfg.model_name, cfg.model.kind)
    for newer in run.checkpoint_files():
        if newer == checkpoint or not rename:
            break
        newer.rename(newer.with_name(newer.name + ".corrupt"))
        print(f"renamed the unreadable {newer.name} to {newer.name}.corrupt")
    return checkpoint


def _refuse_if_alive(run: RunFolder) -> None:
    """Two processes training one run folder would corrupt it. A pid of this host is looked
    up; one of another host (shared storage) is trusted while its heartbeat is fresh."""
    from detach.runs.folder import STALE_AFTER_S, this_host

    if not run.owner_alive():
        return
    status = run.status()
    if status.host and status.host != this_host():
        raise ConfigError(f"run is still {status.state} on host {status.host} (pid {status.pid}, status "
                          f"updated {time.time() - (status.updated or 0):.0f} s ago); stop it there, or "
                          f"resume once its status is {STALE_AFTER_S:.0f} s old", str(run.path))
    raise ConfigError(f"run is still {status.state} (pid {status.pid}); stop it first "
                      f"(kill -TERM {status.pid}) and resume when it is interrupted", str(run.path))


RESUME_OVERRIDABLE = ("train.max_iterations", "train.save_interval", "train.keep_checkpoints",
                      "train.stages.", "eval.")


def _extended_config(run: RunFolder, overrides: Sequence[str], checkpoint: Path) -> RunConfig:
    """The run's config with overrides that cannot invalidate the checkpoints (train longer).

    The past never changes: a longer run extends its last stage (DETACH's schedule is
    written out in train.stages, so it is no longer rescaled), and a schedule stated with
    train.stages.* must give every completed iteration the stage it was trained in."""
    import dataclasses

    from detach.config import load_run_config
    from detach.run_contract import checkpoint_iteration
    from detach.train.schedule import resumed_stages

    for text in overrides:
        key = text.split("=", 1)[0]
        if not key.startswith(RESUME_OVERRIDABLE):
            raise ConfigError(f"cannot change '{key}' when resuming; only "
                              f"{', '.join(RESUME_OVERRIDABLE)}* may change")
    old, new = run.config(), load_run_config(run.config_path, overrides)
    completed = checkpoint_iteration(checkpoint.name)
    if new.train.max_iterations <= completed:
        raise ConfigError(f"train.max_iterations: expected more than the {completed + 1} iterations the "
                          f"run has completed, found {new.train.max_iterations}")
    stated = any(text.split("=", 1)[0].startswith("train.stages.") for text in overrides)
    stages = resumed_stages(old, new, completed, stated)
    if stages is not None:
        new = dataclasses.replace(new, train=dataclasses.replace(new.train, stages=stages))
    return new


def _evaluate(args: argparse.Namespace) -> int:
    target = args.eval
    if not target.exists():
        raise ConfigError("run folder or checkpoint not found", str(target))
    checkpoint = target if target.is_file() else None
    run = RunFolder(target.parent.parent if checkpoint else target)
    if not run.config_path.exists():
        raise ConfigError("not a run folder (no config.yaml)", str(run.path))
    if checkpoint is None and run.latest_checkpoint() is None:
        raise ConfigError("run has no checkpoint to evaluate", str(run.path))
    if args.eval_task is not None and not args.eval_task.exists():
        raise ConfigError("task file not found (--task)", str(args.eval_task))
    from detach.runs.session import evaluate_run

    if checkpoint is not None:
        from detach.train.checkpoints import check_model, read_checkpoint

        cfg = run.config()
        check_model(read_checkpoint(checkpoint), checkpoint, cfg.model_name, cfg.model.kind)
    live = run.owner_alive()
    if live:
        print("the run is still training: its log.mcap is left alone (no episode recorded)")
    path = evaluate_run(run, args.eval_task, checkpoint, args.trials, device=args.device,
                        record=not live)
    print(f"evaluation written to {path}")
    return 0


if __name__ == "__main__":
    sys.exit(main())
