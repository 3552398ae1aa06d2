"""`detach-run`: train, evaluate, resume, sweep, play and export runs; list runs; print the paper's
tables; list config keys.

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
from detach.eval.trial_sets import MIN_TEST_SEED_OFFSET
from detach.runfolder.names import EXPORT_FORMATS
from detach.runfolder.folder import RunFolder, run_folder_name

EXIT_USAGE = 2

DESCRIPTION = """\
Run the DETACH study: train a model on a task, evaluate it, resume it, sweep a grid.

  detach-run train lh1 --model detach                         train, then evaluate
  detach-run train lh3 --model ablation_a1 --dry-run          print the resolved config
  detach-run train follow --model mlp env.character=puppet train.max_iterations=50
  detach-run resume runs/20261123-120000-lh1-detach-s0 [train.max_iterations=2000] [--dry-run]
  detach-run eval runs/20261123-120000-lh1-detach-s0 --task lh2 [--video eval.mp4]
  detach-run sweep configs/sweeps/table3_ablation.yaml --quick --jobs 2
  detach-run play runs/20261123-120000-lh1-detach-s0 [--video play.mp4]
  detach-run export runs/20261123-120000-lh1-detach-s0 --format onnx
  detach-run list                                             table of runs
  detach-run table configs/sweeps/table1.yaml                 the paper's table from eval.json files
  detach-run keys [sim|env|rewards|eval|model|model.detach|train|task]   every config key

Each subcommand has its own --help. The earlier forms still work: `detach-run TASK ...`
(= train), `--resume RUN_DIR`, `--eval RUN_DIR`, `--sweep SWEEP_YAML`, and `--out` for `--runs`.

A task is a name (follow, carry, climb, sit, lh1, lh2, lh3: configs/tasks/ of the working
directory, else the ones shipped with detach) or a path to a task YAML.
--model takes a name from configs/models/ (detach, ablation_a1, ablation_a2, tokenhsi, cml,
mlp) or a path to a model YAML. Overrides are key.path=value with YAML values, e.g.
sim.num_envs=16, scene[0].pos3d=[1,2,0.35]; +key.path=value adds a key that does not exist
(`detach-run keys` lists them). Every run is a folder
<runs>/<YYYYmmdd-HHMMSS>-<task>-<model>-s<seed>/ with config.yaml, status.json, stdout.log,
log.mcap, checkpoints/ and eval.json.
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


def _seed_list(text: str) -> tuple[int, ...]:
    """argparse type of --seeds: distinct seeds, comma-separated (e.g. 0,1,2)."""
    seed = _int_in(0, MAX_SEED)
    seeds = tuple(seed(part.strip()) for part in text.split(","))
    if len(set(seeds)) != len(seeds):
        raise argparse.ArgumentTypeError(f"expected distinct seeds, found {text}")
    return seeds


MAX_SEED = 2**32 - 1
"""NumPy's seeds are 32-bit."""

COMMANDS = ("train", "eval", "resume", "sweep", "play", "export", "list", "table", "keys")
"""`detach-run COMMAND ...`; anything else is the earlier form (TASK, --resume, --eval, --sweep)."""

DEFAULTS = dict(task=None, overrides=[], preset=[], model="detach", seed=0, device="cpu",
                runs=Path("runs"), dry_run=False, resume=None, eval=None, sweep=None, eval_task=None,
                eval_on=[], trials=None, no_eval=False, quick=False, jobs=1, models=None, seeds=None,
                launcher="local", cell=None, video=None, replace=False, test_trials=None, policy_seed=None)
"""Every option a command handler reads; a subcommand's parser sets those it has."""


TEST_TRIALS_CELLS_ONLY = ("--test-trials: the held-out test trials are played only for a sweep's cells "
                          "(detach-run sweep passes it); evaluate other runs on the development trials")


def version() -> str:
    from importlib.metadata import PackageNotFoundError
    from importlib.metadata import version as dist_version

    try:
        return dist_version("detach")
    except PackageNotFoundError:  # a source tree that is not installed
        return "unknown"


def _subparser(command: str, description: str) -> _Parser:
    return _Parser(prog=f"detach-run {command}", description=description,
                   formatter_class=argparse.RawDescriptionHelpFormatter)


def _add_runs(parser: argparse.ArgumentParser, what: str = "parent folder of run folders") -> None:
    parser.add_argument("--runs", "--out", dest="runs", type=Path, default=Path("runs"), metavar="DIR",
                        help=f"{what} (default: runs/; --out is the earlier spelling)")


def _add_device(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--device", default="cpu", help="torch device: cpu, cuda or cuda:N (default: cpu)")


def _add_overrides(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("overrides", nargs="*", metavar="key=value",
                        help="config overrides (YAML values); +key=value adds a new key")


def _add_after_training(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--eval-on", action="append", default=[], metavar="TASK",
                        help="after training, also evaluate on this task (name or YAML; repeatable)")
    parser.add_argument("--no-eval", action="store_true",
                        help="train only; skip the evaluation at the end")


def _add_trials(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--trials", type=_int_in(1), default=None,
                        help="evaluation episodes (default: eval.trials of the config, 100); train and "
                             "resume record it in config.yaml as eval.trials")


def _add_test_trials(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--test-trials", type=_int_in(MIN_TEST_SEED_OFFSET), default=None, metavar="OFFSET",
                        help="a sweep cell only (the sweep passes its test_seed_offset): evaluate on the "
                             "held-out test trials, env seed = run seed + OFFSET, into eval.test.json; "
                             "without it, the development trials (env seed = run seed)")


def _add_eval_task(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--task", dest="eval_task", metavar="TASK",
                        help=f"the task to {what} on, a name or a YAML (default: the run's task); "
                             "a policy trained on LH1 evaluated on LH2/LH3 is the paper's "
                             "environment-generalisation experiment")


def _add_video(parser: argparse.ArgumentParser, what: str) -> None:
    parser.add_argument("--video", type=Path, metavar="FILE.mp4",
                        help=f"render {what} offscreen (MuJoCo, EGL or OSMesa) to this mp4")


def _add_train_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--preset", action="append", default=[], metavar="NAME",
                        help="merge configs/presets/NAME.yaml (or a path) over task and model, before "
                             "the overrides; repeatable (e.g. paper, tokenhsi_ppo). With --sweep: one "
                             "of the sweep's presets (e.g. quick, laptop)")
    parser.add_argument("--model", default="detach",
                        help="model name in configs/models/ or a model YAML path (default: detach)")
    parser.add_argument("--seed", type=_int_in(0, MAX_SEED), default=0,
                        help="random seed, 0 to 2^32-1 (default: 0)")
    _add_device(parser)
    _add_runs(parser)
    parser.add_argument("--dry-run", action="store_true",
                        help="resolve and print the config and the run folder it would "
                             "create, then exit (with --resume: the config it would continue with)")


def _add_sweep_options(parser: argparse.ArgumentParser) -> None:
    parser.add_argument("--quick", action="store_true",
                        help="with --sweep: use the sweep's quick preset (CPU smoke run)")
    parser.add_argument("--jobs", type=_int_in(1), default=1,
                        help="with --sweep: cells run in parallel (default: 1, as each run uses every "
                             "core; detach-scene build defaults to all cores); each gets cores / JOBS torch "
                             "threads, or every core when nothing else of the sweep can run beside it")
    parser.add_argument("--models", default=None, metavar="A,B",
                        help="with --sweep: run only these of the sweep's models (their cells are "
                             "the same as in the whole sweep, so a later full run skips them)")
    parser.add_argument("--seeds", type=_seed_list, default=None, metavar="0,1",
                        help="with --sweep: run these seeds instead of the preset's (a cell of seed S is "
                             "the same as in a sweep that lists S, so `--seeds 0,1` after a one-seed "
                             "sweep trains only seed 1's cells); `detach-run table --seeds` pools them")
    parser.add_argument("--launcher", choices=["local", "ray", "slurm"], default="local",
                        help="with --sweep: a local worker pool, Ray tasks (the cluster of "
                             "RAY_ADDRESS, else a local Ray; the [ray] extra) or SLURM jobs through "
                             "submitit (the [slurm] extra; DETACH_SUBMITIT holds the job parameters "
                             "as JSON, docs/PROTOCOL.md)")


def build_parser() -> argparse.ArgumentParser:
    """The earlier form: `detach-run TASK ...`, `--resume`, `--eval`, `--sweep` (and --help)."""
    parser = _Parser(
        prog="detach-run", description=DESCRIPTION,
        formatter_class=argparse.RawDescriptionHelpFormatter)
    parser.add_argument("--version", action="version", version=f"detach-run {version()}")
    parser.add_argument("task", metavar="TASK", nargs="?",
                        help="task name or YAML (not with --resume/--eval/--sweep); or a COMMAND: "
                             + ", ".join(COMMANDS))
    _add_overrides(parser)
    _add_train_options(parser)
    mode = parser.add_mutually_exclusive_group()
    mode.add_argument("--resume", type=Path, metavar="RUN_DIR",
                      help="continue an interrupted or failed run from its latest checkpoint")
    mode.add_argument("--eval", type=Path, metavar="RUN_DIR|CKPT",
                      help="evaluate a run's policy (or the given checkpoint)")
    mode.add_argument("--sweep", type=Path, metavar="SWEEP_YAML",
                      help="run every unfinished cell of a sweep (configs/sweeps/)")
    _add_eval_task(parser, "evaluate (with --eval)")
    _add_after_training(parser)
    _add_trials(parser)
    _add_test_trials(parser)
    _add_sweep_options(parser)
    _add_video(parser, "with --eval: env 0's first episode")
    parser.add_argument("--cell", help=argparse.SUPPRESS)
    return parser


def build_train_parser() -> argparse.ArgumentParser:
    parser = _subparser("train", "Train a model on a task in a new run folder, then evaluate it.")
    parser.add_argument("task", metavar="TASK", help="task name (lh1, follow, ...) or task YAML")
    _add_overrides(parser)
    _add_train_options(parser)
    _add_after_training(parser)
    _add_trials(parser)
    _add_test_trials(parser)
    parser.add_argument("--cell", help=argparse.SUPPRESS)
    return parser


def build_eval_parser() -> argparse.ArgumentParser:
    parser = _subparser("eval", "Evaluate a run's policy (the checkpoint it selected on validation trials, else "
                                "its newest readable one) or the given checkpoint file; writes eval.json "
                                "(eval_<task>.json for another task). An exported policy (`detach-run export "
                                "--format policy`) is evaluated without its run folder, into "
                                "<file>.eval_<task>_s<seed>.json beside it.")
    parser.add_argument("eval", type=Path, metavar="RUN_DIR|CKPT|POLICY.policy.pt")
    _add_eval_task(parser, "evaluate")
    parser.add_argument("--seed", dest="policy_seed", type=_int_in(0, MAX_SEED), default=None,
                        help="with an exported policy: the trials of this run seed (default: the run's)")
    _add_trials(parser)
    _add_test_trials(parser)
    parser.add_argument("--replace", action="store_true",
                        help="replace an evaluation of the same task with more trials (refused otherwise)")
    _add_device(parser)
    _add_video(parser, "env 0's first evaluation episode")
    return parser


def build_resume_parser() -> argparse.ArgumentParser:
    parser = _subparser("resume", "Continue an interrupted or failed run from its newest readable checkpoint "
                                  "(a run killed before its first checkpoint restarts from iteration 0 with "
                                  "its recorded config); overrides may only train longer "
                                  "(train.max_iterations, ...).")
    parser.add_argument("resume", type=Path, metavar="RUN_DIR")
    _add_overrides(parser)
    _add_device(parser)
    parser.add_argument("--dry-run", action="store_true", help="print the config it would continue with")
    _add_after_training(parser)
    _add_trials(parser)
    _add_test_trials(parser)
    return parser


def build_sweep_parser() -> argparse.ArgumentParser:
    parser = _subparser("sweep", "Run every unfinished cell of a sweep (configs/sweeps/): a graph of runs "
                                 "whose stages start from earlier stages' weights.")
    parser.add_argument("sweep", type=Path, metavar="SWEEP_YAML")
    _add_runs(parser)
    parser.add_argument("--preset", action="append", default=[], metavar="NAME",
                        help="one of the sweep's presets (e.g. quick, laptop)")
    _add_sweep_options(parser)
    _add_trials(parser)
    _add_device(parser)
    return parser


def build_play_parser() -> argparse.ArgumentParser:
    parser = _subparser("play", "Watch a trained policy: episodes live in the viser 3D viewer (the camera "
                                "follows the character), or rendered to an mp4 with --video.")
    parser.add_argument("target", type=Path, metavar="RUN_DIR|CKPT")
    _add_eval_task(parser, "play")
    _add_device(parser)
    _add_video(parser, "the episodes (no viewer)")
    parser.add_argument("--episodes", type=_int_in(1), default=None,
                        help="stop after this many episodes (default: 1 with --video, else until Ctrl-C)")
    parser.add_argument("--steps", type=_int_in(1), default=None,
                        help="stop after this many control steps (default: no limit)")
    parser.add_argument("--host", default="127.0.0.1", help="viewer address (default: 127.0.0.1)")
    parser.add_argument("--port", type=_int_in(1, 65535), default=8081, help="viewer port (default: 8081)")
    parser.add_argument("--width", type=_int_in(16), default=640, help="--video frame width (default: 640)")
    parser.add_argument("--height", type=_int_in(16), default=480, help="--video frame height (default: 480)")
    return parser


def build_export_parser() -> argparse.ArgumentParser:
    parser = _subparser("export", "Export a run's policy (input normaliser and observation history included) "
                                  "for inference outside detach.")
    parser.add_argument("target", type=Path, metavar="RUN_DIR")
    parser.add_argument("--checkpoint", type=_int_in(0), default=None, metavar="N",
                        help="iteration of the checkpoint (default: the run's policy: its selected "
                             "checkpoint, else the newest readable one)")
    parser.add_argument("--format", dest="fmt", choices=["onnx", "jit", "init", "policy"], default="onnx",
                        help="ONNX (onnxruntime), TorchScript, init: a compact start for train.init_from "
                             "(actor and critic in float16, no optimiser, replay or discriminator), or "
                             "policy: the actor alone in float16 with the run's config beside it, which "
                             "`detach-run eval FILE` evaluates without the run folder (default: onnx)")
    parser.add_argument("--output", type=Path, default=None, metavar="FILE",
                        help="where to write it (default: inside the run folder); with a sweep: the folder "
                             "the policies and manifest.json go to")
    ship = parser.add_argument_group("with a sweep YAML as the target: ship the policies of its cells of one stage "
                                     "(--format policy), each evaluated as the sweep evaluates its cell, with a "
                                     "manifest")
    ship.add_argument("--stage", default=None, help="the stage whose cells to export (e.g. lh1)")
    ship.add_argument("--preset", default=None, metavar="NAME", help="the sweep preset the cells were run under")
    ship.add_argument("--seeds", type=_seed_list, default=None, metavar="0,1,2", help="instead of the preset's seeds")
    ship.add_argument("--models", default=None, metavar="A,B", help="only these models (default: the sweep's)")
    _add_runs(parser, "the runs folder holding the sweep's cells")
    _add_trials(parser)
    _add_device(parser)
    return parser


def build_list_parser() -> argparse.ArgumentParser:
    parser = _subparser("list", "Print a table of the runs in a folder.")
    parser.add_argument("positional_runs", type=Path, nargs="?", metavar="RUNS_DIR",
                        help="runs folder (same as --runs)")
    _add_runs(parser, "runs folder")
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
    parser.add_argument("--seeds", type=_seed_list, default=None, metavar="0,1",
                        help="with a sweep: the cells of these seeds instead of the preset's (as run with "
                             "--sweep --seeds); the table pools each model's seeds")
    parser.add_argument("--trial-set", choices=["test", "development"], default=None,
                        help="which evaluations: the held-out test trials (a sweep's default, where it has "
                             "a test_seed_offset) or the development trials (a runs folder's default; "
                             "files end in _dev); docs/PROTOCOL.md, \"Trials\"")
    return parser


def build_keys_parser() -> argparse.ArgumentParser:
    parser = _subparser("keys", "List every config key (override path, type, default, doc), read from the "
                                "config dataclasses (detach/config_schema.py and each model kind's class).")
    parser.add_argument("section", nargs="?", default=None,
                        help="a section (task, sim, env, rewards, eval, model, train), a model kind "
                             "(model.detach, model.tokenhsi, ...) or a key prefix (train.amp); default: all")
    return parser


PARSERS: dict[str, Callable[[], argparse.ArgumentParser]] = {
    "train": build_train_parser, "eval": build_eval_parser, "resume": build_resume_parser,
    "sweep": build_sweep_parser, "play": build_play_parser, "export": build_export_parser,
    "list": build_list_parser, "table": build_table_parser, "keys": build_keys_parser}


def task_path(task: str | Path, option: str = "") -> Path:
    """A task name (`lh1`) or path, as the path of its YAML; ConfigError naming the option."""
    from detach.config import find_task_file

    try:
        return find_task_file(task)
    except ConfigError as exc:
        if option:
            raise ConfigError(f"{option}: {exc}") from None
        raise


def check_device(device: str) -> None:
    """Fail early, as a user error, on a device this machine does not have."""
    if device == "cpu":
        return
    index = device.removeprefix("cuda:") if device.startswith("cuda:") else ""
    if not (device == "cuda" or index.isdigit()):
        raise ConfigError(f"--device: expected cpu, cuda or cuda:N, found '{device}'")
    import torch

    if not torch.cuda.is_available():
        raise ConfigError(f"--device {device}: CUDA is not available on this machine "
                          f"(torch {torch.__version__}); use --device cpu")
    if index and int(index) >= torch.cuda.device_count():
        raise ConfigError(f"--device {device}: this machine has {torch.cuda.device_count()} CUDA device(s) "
                          f"(cuda:0 to cuda:{torch.cuda.device_count() - 1})")


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


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    """`detach-run COMMAND ...` or the earlier forms, as one namespace with `command` set and
    every option of `DEFAULTS` present."""
    argv = list(argv)
    if argv and argv[0] in PARSERS:
        command, parser = argv[0], PARSERS[argv[0]]()
        args = parser.parse_intermixed_args(argv[1:]) if command in ("train", "resume") \
            else parser.parse_args(argv[1:])
    else:
        args = build_parser().parse_intermixed_args(argv)
        command = "sweep" if args.sweep else "resume" if args.resume else "eval" if args.eval else "train"
        if command != "train" and args.task:
            # No TASK in these modes: a positional key=value is an override.
            args.overrides, args.task = [args.task, *args.overrides], None
    for key, value in DEFAULTS.items():
        if not hasattr(args, key):
            setattr(args, key, value)
    args.command = command
    return args


def _main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    try:
        args = parse_args(argv)
        if args.command == "list":
            from detach.runs.listing import print_runs

            return print_runs(args.positional_runs or args.runs)
        if args.command == "table":
            from detach.runs.tables_cli import print_table

            return print_table(args.source, args.runs, args.kind, args.out, args.task, args.sgr,
                               "quick" if args.quick else args.preset, args.seeds, args.trial_set)
        if args.command == "keys":
            return _keys(args.section)
        if args.command == "export":
            return _export(args)
        check_device(args.device)
        if args.command == "play":
            return _play(args)
        if args.command == "sweep":
            from detach.runs.sweep import run_sweep

            if len(args.preset) > 1:
                raise ConfigError("--sweep takes one --preset (one of the sweep's presets)")
            failed = run_sweep(args.sweep, args.runs, args.jobs, args.quick, args.device,
                               launcher=args.launcher, preset=next(iter(args.preset), None),
                               models=args.models.split(",") if args.models else None, seeds=args.seeds)
            return 1 if failed else 0
        if args.command == "resume":
            return _resume(args)
        if args.command == "eval":
            return _evaluate(args)
        return _train(args)
    except ConfigError as exc:
        return _fail(exc)


def _keys(section: str | None) -> int:
    from detach.config_keys import format_keys, select

    try:
        keys = select(section)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    print(format_keys(keys))
    return 0


def _export(args: argparse.Namespace) -> int:
    """`detach.runs.export.export_run(run_dir, checkpoint=N|None, fmt='onnx'|'jit'|'init', output=Path|None)`;
    of a sweep, `detach.runs.ship.ship_sweep`."""
    if args.target.suffix in (".yaml", ".yml"):
        return _ship(args)
    from detach.runs.export import export_run

    exported = export_run(args.target, checkpoint=args.checkpoint, fmt=args.fmt, output=args.output)
    print(f"exported to {exported}")
    return 0


def _ship(args: argparse.Namespace) -> int:
    if args.stage is None or args.output is None:
        raise ConfigError("exporting a sweep's policies needs --stage (e.g. lh1) and --output FOLDER", str(args.target))
    if args.fmt not in ("onnx", "policy") or args.checkpoint is not None:  # onnx: the default, not chosen
        raise ConfigError("a sweep's policies are exported as --format policy, each cell's own policy "
                          "(no --checkpoint)", str(args.target))
    from detach.runs.ship import ship_sweep

    manifest = ship_sweep(args.target, args.runs, args.output, args.stage, preset=args.preset, seeds=args.seeds,
                          models=args.models.split(",") if args.models else None, trials=args.trials,
                          device=args.device)
    print(f"manifest written to {manifest}")
    return 0


def _play(args: argparse.Namespace) -> int:
    run, checkpoint = _run_and_checkpoint(args.target)
    eval_task = task_path(args.eval_task, "--task") if args.eval_task else None
    if args.video is not None:
        _choose_gl()
    from server.play_view import play

    return play(run, checkpoint, eval_task, device=args.device, video=args.video, episodes=args.episodes,
                steps=args.steps, host=args.host, port=args.port, size=(args.width, args.height))


def _run_and_checkpoint(target: Path) -> tuple[RunFolder, Path | None]:
    """A run folder or one of its checkpoint files -> (run, that checkpoint or None)."""
    if not target.exists():
        raise ConfigError("run folder or checkpoint not found", str(target))
    checkpoint = target if target.is_file() else None
    run = RunFolder(target.parent.parent if checkpoint else target)
    if not run.config_path.exists():
        raise ConfigError("not a run folder (no config.yaml)", str(run.path))
    if checkpoint is None and run.latest_checkpoint() is None:
        raise ConfigError("run has no checkpoint", str(run.path))
    return run, checkpoint


def _train(args: argparse.Namespace) -> int:
    if args.task is None:
        raise ConfigError("missing TASK (or use a command: " + ", ".join(COMMANDS) + ")")
    task = task_path(args.task)
    eval_on = [task_path(extra, "--eval-on") for extra in args.eval_on]
    if args.test_trials is not None and not args.cell:
        raise ConfigError(TEST_TRIALS_CELLS_ONLY)
    from detach.train.checks import complete_run_config

    cfg = complete_run_config(resolve(task, args.model, args.overrides, seed=args.seed, device=args.device,
                                      presets=args.preset))
    cfg = _with_trials(cfg, args.trials)  # recorded: a resume or re-evaluation repeats them
    if args.dry_run:
        sys.stdout.write(dump(cfg))
        print(f"# run folder: {args.runs / run_folder_name(cfg)}")
        return 0
    from detach.train.distributed import is_worker

    if is_worker():  # torchrun rank > 0: trains in step with rank 0, which alone writes the run folder
        from detach.train.setup import train_worker

        train_worker(cfg)
        return 0
    from detach.runs.job import run_job
    from detach.runs.session import train_and_evaluate

    try:
        run = RunFolder.create(args.runs, cfg)
        if args.cell:
            run.set_state("queued", cell=args.cell)
    except OSError as exc:
        blocker = next((p for p in (Path(args.runs), *Path(args.runs).parents) if p.exists()), None)
        why = f"{blocker} is a file" if blocker is not None and not blocker.is_dir() else exc.strerror or exc
        raise ConfigError(f"cannot create a run folder under --runs {args.runs} ({why}); "
                          f"expected a writable folder") from None
    print(f"run folder: {run.path}")
    code = run_job(run, lambda r: train_and_evaluate(
        r, resume=False, eval_tasks=eval_on, trials=None, evaluate=not args.no_eval,
        test_offset=args.test_trials))
    print(f"run folder: {run.path}")
    if code == 0 and not args.cell:
        print(f"next: detach-dashboard --runs {args.runs}  (curves, 3D replay of the evaluation, tables; "
              f"loopback http://127.0.0.1:8080)")
    return code


def _with_trials(cfg: RunConfig, trials: int | None) -> RunConfig:
    """`--trials N` as `eval.trials` of the config (None: the config's own)."""
    import dataclasses

    if trials is None:
        return cfg
    return dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, trials=trials))


def _resume(args: argparse.Namespace) -> int:
    run = RunFolder(args.resume)
    if not run.config_path.exists():
        raise ConfigError("not a run folder (no config.yaml)", str(args.resume))
    if run.latest_checkpoint() is None:
        return _restart(run, args)
    _refuse_if_alive(run)
    _check_test_trials(run, args.test_trials)
    cfg = run.config()  # validates the stored config as a user error, not a traceback
    checkpoint = _resume_checkpoint(run, cfg, rename=not args.dry_run)
    new = _extended_config(run, args.overrides, checkpoint) if args.overrides else cfg
    new = _with_trials(new, args.trials)
    if args.dry_run:
        sys.stdout.write(dump(new))
        print(f"# would resume {run.path} from {checkpoint.name}")
        return 0
    from detach.runs.provenance import code_change_since

    warning = code_change_since(run)
    if warning:
        print(warning, flush=True)
    return _take_up(run, args, cfg, new, f"resuming {run.path} from {checkpoint.name}", checkpoint)


def _take_up(run: RunFolder, args: argparse.Namespace, cfg: RunConfig, new: RunConfig, said: str,
             checkpoint: Path | None) -> int:
    """Write the run's config if `--resume` changed it, then train on from `checkpoint` (None:
    from iteration 0) and evaluate, as the run's own job."""
    if new != cfg:
        from detach.runfolder.atomic import atomic_write_text

        atomic_write_text(run.config_path, dump(new))
    from detach.runs.job import run_job
    from detach.runs.session import train_and_evaluate

    eval_on = [task_path(extra, "--eval-on") for extra in args.eval_on]
    print(said, flush=True)
    return run_job(run, lambda r: train_and_evaluate(
        r, resume=checkpoint is not None, eval_tasks=eval_on, trials=None, evaluate=not args.no_eval,
        device=args.device, checkpoint=checkpoint, test_offset=args.test_trials))


def _check_test_trials(run: RunFolder, test_offset: int | None) -> None:
    """Refuse --test-trials for a run that is no sweep cell before anything trains."""
    from detach.eval.trial_sets import TrialSetError
    from detach.runs.session import trial_set_of

    try:
        trial_set_of(run, test_offset)
    except TrialSetError as exc:
        raise ConfigError(str(exc)) from None


def _restart(run: RunFolder, args: argparse.Namespace) -> int:
    """A run killed before its first checkpoint: nothing to resume from, so it trains again
    from iteration 0 with its recorded config (a new log.mcap replaces the old one)."""
    from detach.config import load_run_config

    try:
        run.status()
    except (OSError, ValueError) as exc:
        raise ConfigError(f"run has no checkpoint, and its status.json is unreadable ({exc}); "
                          f"expected a run folder that was started", str(run.path)) from None
    _refuse_if_alive(run)
    _check_test_trials(run, args.test_trials)
    cfg = run.config()
    for text in args.overrides:
        key = text.split("=", 1)[0]
        if not key.startswith(RESUME_OVERRIDABLE):
            raise ConfigError(f"cannot change '{key}' when resuming; only "
                              f"{', '.join(k + '*' if k.endswith('.') else k for k in RESUME_OVERRIDABLE)} may change")
    new = _with_trials(load_run_config(run.config_path, args.overrides) if args.overrides else cfg, args.trials)
    if args.dry_run:
        sys.stdout.write(dump(new))
        print(f"# would restart {run.path} from iteration 0 (it has no checkpoint yet)")
        return 0
    return _take_up(run, args, cfg, new, f"{run.path} has no checkpoint yet: restarting it from iteration 0 "
                                         f"with its recorded config", None)


def _resume_checkpoint(run: RunFolder, cfg: RunConfig, rename: bool = True) -> Path:
    """The newest checkpoint that reads back whole and is of the run's model. Newer files that
    do not read back (truncated, corrupt) are renamed *.corrupt: the resumed run writes
    those iterations again, and no reader should pick the broken file meanwhile."""
    from detach.train.checkpoints import check_model, newest_readable_checkpoint, read_checkpoint

    checkpoint = newest_readable_checkpoint(run.path)
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
    from detach.runfolder.liveness import STALE_AFTER_S, this_host

    if not run.owner_alive():
        return
    status = run.status()
    if status.host and status.host != this_host():
        raise ConfigError(f"run is still {status.state} on host {status.host} (pid {status.pid}, status "
                          f"updated {time.time() - (status.updated or 0):.0f} s ago); stop it there, or "
                          f"resume once its status is {STALE_AFTER_S:.0f} s old", str(run.path))
    raise ConfigError(f"run is still {status.state} (pid {status.pid}); stop it first "
                      f"(kill -TERM {status.pid}) and resume when it is interrupted", str(run.path))


# What a resume may change: how long and how often to save, how to evaluate, and how many
# CPU threads torch uses (speed, not numbers: a run may go on where there are more cores).
RESUME_OVERRIDABLE = ("train.max_iterations", "train.save_interval", "train.keep_checkpoints",
                      "train.torch_threads", "train.stages.", "eval.")


def _extended_config(run: RunFolder, overrides: Sequence[str], checkpoint: Path) -> RunConfig:
    """The run's config with overrides that cannot invalidate the checkpoints (train longer).

    The past never changes: a longer run extends its last stage (DETACH's schedule is
    written out in train.stages, so it is no longer rescaled), and a schedule stated with
    train.stages.* must give every completed iteration the stage it was trained in."""
    import dataclasses

    from detach.config import load_run_config
    from detach.runfolder.names import checkpoint_iteration
    from detach.train.schedule import resumed_stages

    for text in overrides:
        key = text.split("=", 1)[0]
        if not key.startswith(RESUME_OVERRIDABLE):
            raise ConfigError(f"cannot change '{key}' when resuming; only "
                              f"{', '.join(k + '*' if k.endswith('.') else k for k in RESUME_OVERRIDABLE)} may change")
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
    eval_task = task_path(args.eval_task, "--task") if args.eval_task is not None else None
    if Path(args.eval).name.endswith(EXPORT_FORMATS["policy"]):
        return _evaluate_policy_file(args, eval_task)
    if args.policy_seed is not None:
        raise ConfigError("--seed: with an exported policy only (a run is evaluated on its own seed's trials)")
    run, checkpoint = _run_and_checkpoint(args.eval)
    if args.video is not None:
        _choose_gl()  # before anything imports mujoco
    from detach.runs.session import evaluate_run, smaller_evaluation

    _check_test_trials(run, args.test_trials)
    smaller = None if args.replace else smaller_evaluation(run, eval_task, args.trials, args.test_trials)
    if smaller is not None:
        raise ConfigError(smaller)
    if checkpoint is not None:
        from detach.train.checkpoints import check_model, read_checkpoint

        cfg = run.config()
        check_model(read_checkpoint(checkpoint), checkpoint, cfg.model_name, cfg.model.kind)
    live = run.owner_alive()
    if live:
        print("the run is still training: its log.mcap is left alone (no episode recorded)")
    path = evaluate_run(run, eval_task, checkpoint, args.trials, device=args.device, record=not live,
                        test_offset=args.test_trials)
    print(f"evaluation written to {path}")
    if args.video is not None:
        from detach.runs.play import play_video

        play_video(run, checkpoint, eval_task, args.video, device=args.device, episodes=1)
    return 0


def _evaluate_policy_file(args: argparse.Namespace, eval_task: Path | None) -> int:
    from detach.eval.trial_sets import TrialSetError
    from detach.runs.session import evaluate_policy_file
    from detach.train.checkpoints import CheckpointError

    policy = Path(args.eval)
    if not policy.is_file():
        raise ConfigError("exported policy not found", str(policy))
    if args.video is not None:
        raise ConfigError("--video: with a run folder only")
    try:
        path = evaluate_policy_file(policy, eval_task, args.policy_seed, args.trials, device=args.device,
                                    test_offset=args.test_trials)
    except (TrialSetError, CheckpointError) as exc:
        raise ConfigError(str(exc)) from None
    print(f"evaluation written to {path}")
    return 0


def _choose_gl() -> None:
    from detach.runs.video import VideoError, choose_gl

    try:
        choose_gl()
    except VideoError as exc:
        raise ConfigError(f"--video: {exc}") from None


if __name__ == "__main__":
    sys.exit(main())
