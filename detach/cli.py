"""`detach-run`: train, evaluate, resume, sweep, play and export runs; list runs; print the paper's
tables; list config keys.

This module only parses: each command calls a function of the API, `detach.runs.actions`
(list, table and keys their report modules). User errors (bad config, bad flag, missing file)
print one line and exit with code 2 (`detach.runs.command`); tracebacks are reserved for bugs
(and go to the run's stdout.log). The earlier forms (`detach-run TASK`, `--resume`, `--eval`,
`--sweep`) still work for one release, with a one-line deprecation on stderr.
"""

from __future__ import annotations

import argparse
import sys
import typing
from pathlib import Path
from typing import Callable, Sequence

from detach.config import ConfigError
from detach.eval.trial_sets import MIN_TEST_SEED_OFFSET
from detach.runs import actions
from detach.runs.command import run_command

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

Each subcommand has its own --help. The earlier forms are deprecated (they still work, for one
release, and say so on stderr): `detach-run TASK ...` (= train), `--resume RUN_DIR`,
`--eval RUN_DIR`, `--sweep SWEEP_YAML`; `--out` is still accepted for `--runs`.

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
                        help="use the sweep's quick preset (CPU smoke run)")
    parser.add_argument("--jobs", type=_int_in(1), default=1,
                        help="cells run in parallel (default: 1, as each run uses every "
                             "core; detach-scene build defaults to all cores); each gets cores / JOBS torch "
                             "threads, or every core when nothing else of the sweep can run beside it")
    parser.add_argument("--models", default=None, metavar="A,B",
                        help="run only these of the sweep's models (their cells are "
                             "the same as in the whole sweep, so a later full run skips them)")
    parser.add_argument("--seeds", type=_seed_list, default=None, metavar="0,1",
                        help="run these seeds instead of the preset's (a cell of seed S is "
                             "the same as in a sweep that lists S, so `--seeds 0,1` after a one-seed "
                             "sweep trains only seed 1's cells); `detach-run table --seeds` pools them")
    parser.add_argument("--launcher", choices=["local", "ray", "slurm"], default="local",
                        help="a local worker pool, Ray tasks (the cluster of "
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
                        help="replace an evaluation of the same task that has more trials than this one "
                             "(refused otherwise; one with as many trials or more is replaced without it)")
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
                       help="with a sweep: the cells of this sweep preset (as `detach-run sweep --preset` ran them)")
    which.add_argument("--quick", action="store_true", help="with a sweep: the cells of its quick preset")
    parser.add_argument("--seeds", type=_seed_list, default=None, metavar="0,1",
                        help="with a sweep: the cells of these seeds instead of the preset's (as `detach-run "
                             "sweep --seeds` ran them); the table pools each model's seeds")
    parser.add_argument("--trial-set", choices=["test", "development"], default=None,
                        help="which evaluations: the held-out test trials (a sweep's default, where it has "
                             "a test_seed_offset) or the development trials (a runs folder's default; "
                             "files end in _dev); docs/PROTOCOL.md, \"Trials\"")
    return parser


def build_keys_parser() -> argparse.ArgumentParser:
    parser = _subparser("keys", "List every config key (override path, type, default, doc), read from the "
                                "config dataclasses (detach/config/schema.py and each model kind's class).")
    parser.add_argument("section", nargs="?", default=None,
                        help="a section (task, sim, env, rewards, eval, model, train), a model kind "
                             "(model.detach, model.tokenhsi, ...) or a key prefix (train.amp); default: all")
    return parser


PARSERS: dict[str, Callable[[], argparse.ArgumentParser]] = {
    "train": build_train_parser, "eval": build_eval_parser, "resume": build_resume_parser,
    "sweep": build_sweep_parser, "play": build_play_parser, "export": build_export_parser,
    "list": build_list_parser, "table": build_table_parser, "keys": build_keys_parser}


DEPRECATED = {"train": "`detach-run TASK ...` is now `detach-run train TASK ...`",
              "resume": "`detach-run --resume RUN_DIR` is now `detach-run resume RUN_DIR`",
              "eval": "`detach-run --eval RUN_DIR` is now `detach-run eval RUN_DIR`",
              "sweep": "`detach-run --sweep SWEEP_YAML` is now `detach-run sweep SWEEP_YAML`"}
"""The earlier form of each command, as its deprecation line says it."""


def main(argv: Sequence[str] | None = None) -> int:
    """Run the command; SIGTERM anywhere (start-up included) ends it like Ctrl-C: exit 130."""
    return run_command(lambda: _main(list(sys.argv[1:] if argv is None else argv)))


def parse_args(argv: Sequence[str]) -> argparse.Namespace:
    """`detach-run COMMAND ...` or the earlier forms, as one namespace with `command` set and
    every option of `DEFAULTS` present; `deprecated` says which earlier form was used (or None)."""
    argv = list(argv)
    deprecated = None
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
        if argv:
            deprecated = f"deprecated: {DEPRECATED[command]} (the earlier form goes in the next release)"
    for key, value in DEFAULTS.items():
        if not hasattr(args, key):
            setattr(args, key, value)
    args.command, args.deprecated = command, deprecated
    return args


def _main(argv: Sequence[str]) -> int:
    args = parse_args(argv)
    if args.deprecated:
        print(f"detach-run: {args.deprecated}", file=sys.stderr)
    return HANDLERS[args.command](args)


def _train(args: argparse.Namespace) -> int:
    if args.task is None:
        raise ConfigError("missing TASK (or use a command: " + ", ".join(COMMANDS) + ")")
    options = dict(seed=args.seed, device=args.device, presets=args.preset, overrides=args.overrides,
                   eval_on=args.eval_on, trials=args.trials, test_offset=args.test_trials, cell=args.cell)
    if args.dry_run:
        actions.print_dry_run(actions.train_config(args.task, args.model, **options), args.runs)
        return 0
    outcome = actions.train(args.task, args.model, runs=args.runs, evaluate=not args.no_eval, **options)
    if outcome.code == 0 and outcome.run is not None and not args.cell:
        print(f"next: detach-dashboard --runs {args.runs}  (curves, 3D replay of the evaluation, tables; "
              f"loopback http://127.0.0.1:8080)")
    return outcome.code


def _resume(args: argparse.Namespace) -> int:
    options = dict(overrides=args.overrides, device=args.device, trials=args.trials, test_offset=args.test_trials)
    if args.dry_run:
        actions.print_resume_plan(actions.resume_plan(args.resume, **options))
        return 0
    return actions.resume(args.resume, eval_on=args.eval_on, evaluate=not args.no_eval, **options).code


def _evaluate(args: argparse.Namespace) -> int:
    actions.evaluate(args.eval, task=args.eval_task, trials=args.trials, test_offset=args.test_trials,
                     replace=args.replace, device=args.device, seed=args.policy_seed, video=args.video)
    return 0


def _sweep(args: argparse.Namespace) -> int:
    if len(args.preset) > 1:
        raise ConfigError("--sweep takes one --preset (one of the sweep's presets)")
    failed = actions.sweep(args.sweep, runs=args.runs, jobs=args.jobs, quick=args.quick, device=args.device,
                           launcher=args.launcher, preset=next(iter(args.preset), None),
                           models=args.models.split(",") if args.models else None, seeds=args.seeds)
    return 1 if failed else 0


def _play(args: argparse.Namespace) -> int:
    actions.play(args.target, task=args.eval_task, device=args.device, video=args.video, episodes=args.episodes,
                 steps=args.steps, host=args.host, port=args.port, size=(args.width, args.height))
    return 0


def _export(args: argparse.Namespace) -> int:
    """A run's policy (`actions.export`), or with a sweep YAML its cells' (`actions.export_sweep`)."""
    if args.target.suffix in (".yaml", ".yml"):
        actions.export_sweep(args.target, stage=args.stage, output=args.output, runs=args.runs, preset=args.preset,
                             seeds=args.seeds, models=args.models.split(",") if args.models else None,
                             trials=args.trials, device=args.device, fmt=args.fmt, checkpoint=args.checkpoint)
    else:
        actions.export(args.target, checkpoint=args.checkpoint, fmt=args.fmt, output=args.output)
    return 0


def _list(args: argparse.Namespace) -> int:
    from detach.runs.listing import print_runs

    return print_runs(args.positional_runs or args.runs)


def _table(args: argparse.Namespace) -> int:
    from detach.runs.tables_cli import print_table

    return print_table(args.source, args.runs, args.kind, args.out, args.task, args.sgr,
                       "quick" if args.quick else args.preset, args.seeds, args.trial_set)


def _keys(args: argparse.Namespace) -> int:
    from detach.config.keys import format_keys, select

    try:
        keys = select(args.section)
    except ValueError as exc:
        raise ConfigError(str(exc)) from None
    print(format_keys(keys))
    return 0


HANDLERS: dict[str, Callable[[argparse.Namespace], int]] = {
    "train": _train, "eval": _evaluate, "resume": _resume, "sweep": _sweep, "play": _play,
    "export": _export, "list": _list, "table": _table, "keys": _keys}


if __name__ == "__main__":
    sys.exit(main())
