"""The Python API under `detach-run`: train, resume, evaluate, export and play a run, and run a
sweep, as functions of typed arguments.

`detach.cli` parses a command line and calls one of these; a sweep's cells call them through
`detach.runs.worker`. A user's mistake (an unknown task, a run that is not resumable, a device
this machine lacks) is a `ConfigError` raised before anything is written, which the command
line prints as one line with exit code 2. Training itself runs as the run folder's job
(`detach.runs.job.run_job`): its outcome is the job's exit code (0 finished, 1 failed, 130
interrupted) in a `RunOutcome`, as the run's status.json says. Progress lines (the run folder,
where an evaluation was written) are printed as the command line has always printed them.
Heavy modules (torch, MuJoCo) are imported inside the functions, so `detach-run --help` stays fast.
"""

from __future__ import annotations

import dataclasses
import sys
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Sequence

from detach.config import ConfigError, dump
from detach.config.schema import RunConfig
from detach.runfolder.folder import RunFolder, run_folder_name
from detach.runfolder.names import EXPORT_FORMATS

if TYPE_CHECKING:
    from detach.runs.export import Exported
    from detach.runs.resume_policy import ResumePlan

VIEWER_ENTRY_POINTS = "detach.viewers"
"""Entry-point group of the live viewer of `play` (`live`: the dashboard's, `server.play_view`)."""

TEST_TRIALS_CELLS_ONLY = ("--test-trials: the held-out test trials are played only for a sweep's cells "
                          "(detach-run sweep passes it); evaluate other runs on the development trials")


@dataclass(frozen=True)
class RunOutcome:
    """A run folder trained (or resumed) and evaluated, and how its job ended."""

    run: Path | None
    """None on a torchrun rank > 0, which writes no run folder."""
    code: int
    """The job's exit code: 0 finished, 1 failed, 130 interrupted."""


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


def with_trials(cfg: RunConfig, trials: int | None) -> RunConfig:
    """`--trials N` as `eval.trials` of the config (None: the config's own): recorded, so that a
    resume or a re-evaluation repeats them."""
    if trials is None:
        return cfg
    return dataclasses.replace(cfg, eval=dataclasses.replace(cfg.eval, trials=trials))


# ------------------------------------------------------------------------------- train
def train_config(task: str | Path, model: str = "detach", *, seed: int = 0, device: str = "cpu",
                 presets: Sequence[str] = (), overrides: Sequence[str] = (), eval_on: Sequence[str | Path] = (),
                 trials: int | None = None, test_offset: int | None = None, cell: str | None = None) -> RunConfig:
    """The resolved, checked config `train` would run with (`--dry-run` prints it)."""
    check_device(device)
    task = task_path(task)
    for extra in eval_on:
        task_path(extra, "--eval-on")
    if test_offset is not None and not cell:
        raise ConfigError(TEST_TRIALS_CELLS_ONLY)
    from detach.train.run_config import resolve_run

    cfg = resolve_run(task, model, list(overrides), seed=seed, device=device, presets=list(presets))
    return with_trials(cfg, trials)


def train(task: str | Path, model: str = "detach", *, seed: int = 0, device: str = "cpu",
          runs: str | Path = Path("runs"), presets: Sequence[str] = (), overrides: Sequence[str] = (),
          eval_on: Sequence[str | Path] = (), trials: int | None = None, evaluate: bool = True,
          test_offset: int | None = None, cell: str | None = None) -> RunOutcome:
    """Train `model` on `task` in a new run folder under `runs`, then evaluate it on its task and
    on `eval_on` (unless not `evaluate`). `cell`: the sweep cell it is (status.json); only a cell
    plays the held-out test trials (`test_offset`)."""
    cfg = train_config(task, model, seed=seed, device=device, presets=presets, overrides=overrides,
                       eval_on=eval_on, trials=trials, test_offset=test_offset, cell=cell)
    eval_tasks = [task_path(extra) for extra in eval_on]
    from detach.train.distributed import is_worker

    if is_worker():  # torchrun rank > 0: trains in step with rank 0, which alone writes the run folder
        from detach.train.setup import train_worker

        train_worker(cfg)
        return RunOutcome(None, 0)
    from detach.runs.job import run_job
    from detach.runs.session import train_and_evaluate

    runs = Path(runs)
    try:
        run = RunFolder.create(runs, cfg)
        if cell:
            run.set_state("queued", cell=cell)
    except OSError as exc:
        blocker = next((p for p in (runs, *runs.parents) if p.exists()), None)
        why = f"{blocker} is a file" if blocker is not None and not blocker.is_dir() else exc.strerror or exc
        raise ConfigError(f"cannot create a run folder under --runs {runs} ({why}); "
                          f"expected a writable folder") from None
    print(f"run folder: {run.path}")
    code = run_job(run, lambda r: train_and_evaluate(  # the config in memory: config.yaml is not read back
        r, cfg, resume=False, eval_tasks=eval_tasks, trials=None, evaluate=evaluate, test_offset=test_offset))
    print(f"run folder: {run.path}")
    return RunOutcome(run.path, code)


def print_dry_run(cfg: RunConfig, runs: str | Path) -> None:
    """What `train --dry-run` shows: the config, and the folder it would create."""
    sys.stdout.write(dump(cfg))
    print(f"# run folder: {Path(runs) / run_folder_name(cfg)}")


# ------------------------------------------------------------------------------- resume
def resume_plan(run_dir: str | Path, *, overrides: Sequence[str] = (), device: str = "cpu",
                trials: int | None = None, test_offset: int | None = None, rename: bool = False) -> ResumePlan:
    """How `resume` would take up the run (`--dry-run` prints it); `rename`: set newer unreadable
    checkpoints aside (*.corrupt), as `resume` does."""
    from detach.runs.resume_policy import plan_resume

    check_device(device)
    plan = plan_resume(Path(run_dir), overrides, test_offset, rename=rename)
    return dataclasses.replace(plan, config=with_trials(plan.config, trials))


def print_resume_plan(plan: ResumePlan) -> None:
    """What `resume --dry-run` shows: the config it would continue with, and from where."""
    sys.stdout.write(dump(plan.config))
    if plan.checkpoint is not None:
        print(f"# would resume {plan.run.path} from {plan.checkpoint.name}")
    else:
        print(f"# would restart {plan.run.path} from iteration 0 (it has no checkpoint yet)")


def resume(run_dir: str | Path, *, overrides: Sequence[str] = (), device: str = "cpu",
           eval_on: Sequence[str | Path] = (), trials: int | None = None, evaluate: bool = True,
           test_offset: int | None = None) -> RunOutcome:
    """Continue an interrupted or failed run from its newest readable checkpoint (a run killed
    before its first one restarts from iteration 0), then evaluate it; `overrides` may only
    train longer (`detach.runs.resume_policy`)."""
    plan = resume_plan(run_dir, overrides=overrides, device=device, trials=trials, test_offset=test_offset,
                       rename=True)
    run = plan.run
    if plan.checkpoint is not None:
        from detach.runs.provenance import code_change_since

        warning = code_change_since(run)
        if warning:
            print(warning, flush=True)
        said = f"resuming {run.path} from {plan.checkpoint.name}"
    else:
        said = f"{run.path} has no checkpoint yet: restarting it from iteration 0 with its recorded config"
    if plan.config != plan.stored:
        from detach.runfolder.atomic import atomic_write_text

        atomic_write_text(run.config_path, dump(plan.config))
    from detach.runs.job import run_job
    from detach.runs.session import train_and_evaluate

    eval_tasks = [task_path(extra, "--eval-on") for extra in eval_on]
    print(said, flush=True)
    code = run_job(run, lambda r: train_and_evaluate(
        r, plan.config, resume=plan.checkpoint is not None, eval_tasks=eval_tasks, trials=None, evaluate=evaluate,
        device=device, checkpoint=plan.checkpoint, test_offset=test_offset))
    return RunOutcome(run.path, code)


# ------------------------------------------------------------------------------- evaluate
def evaluate(target: str | Path, *, task: str | Path | None = None, trials: int | None = None,
             test_offset: int | None = None, replace: bool = False, device: str = "cpu",
             seed: int | None = None, video: str | Path | None = None) -> Path:
    """Evaluate a run's policy (or the checkpoint file `target`, or an exported .policy.pt) on
    its task or `task`; returns the eval file written. A smaller evaluation does not replace a
    larger one of the same task unless `replace`. `seed`: an exported policy's run seed."""
    check_device(device)
    eval_task = task_path(task, "--task") if task is not None else None
    target = Path(target)
    if target.name.endswith(EXPORT_FORMATS["policy"]):
        return _evaluate_policy_file(target, eval_task, seed, trials, device, test_offset, video)
    if seed is not None:
        raise ConfigError("--seed: with an exported policy only (a run is evaluated on its own seed's trials)")
    run, checkpoint = run_and_checkpoint(target)
    if video is not None:
        _choose_gl()  # before anything imports mujoco
    from detach.runs.resume_policy import check_test_trials
    from detach.runs.session import evaluate_run, smaller_evaluation

    check_test_trials(run, test_offset)
    smaller = None if replace else smaller_evaluation(run, eval_task, trials, test_offset)
    if smaller is not None:
        raise ConfigError(smaller)
    if checkpoint is not None:
        from detach.train.checkpoints import check_model, read_checkpoint

        cfg = run.config()
        check_model(read_checkpoint(checkpoint), checkpoint, cfg.model_name, cfg.model.kind)
    live = run.owner_alive()
    if live:
        print("the run is still training: its log.mcap is left alone (no episode recorded)")
    path = evaluate_run(run, eval_task, checkpoint, trials, device=device, record=not live, test_offset=test_offset)
    print(f"evaluation written to {path}")
    if video is not None:
        from detach.runs.play import play_video

        play_video(run, checkpoint, eval_task, Path(video), device=device, episodes=1)
    return path


def _evaluate_policy_file(policy: Path, eval_task: Path | None, seed: int | None, trials: int | None,
                          device: str, test_offset: int | None, video: str | Path | None) -> Path:
    from detach.eval.trial_sets import TrialSetError
    from detach.runs.session import evaluate_policy_file
    from detach.train.checkpoints import CheckpointError

    if not policy.is_file():
        raise ConfigError("exported policy not found", str(policy))
    if video is not None:
        raise ConfigError("--video: with a run folder only")
    try:
        path = evaluate_policy_file(policy, eval_task, seed, trials, device=device, test_offset=test_offset)
    except (TrialSetError, CheckpointError) as exc:
        raise ConfigError(str(exc)) from None
    print(f"evaluation written to {path}")
    return path


def run_and_checkpoint(target: Path) -> tuple[RunFolder, Path | None]:
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


def _choose_gl() -> None:
    from detach.runs.video import VideoError, choose_gl

    try:
        choose_gl()
    except VideoError as exc:
        raise ConfigError(f"--video: {exc}") from None


# ------------------------------------------------------------------------------- export, play, sweep
def export(target: str | Path, *, checkpoint: int | None = None, fmt: str = "onnx",
           output: str | Path | None = None) -> Exported:
    """Export a run's policy (`detach.runs.export.export_run`) as onnx, jit, init or policy."""
    from detach.runs.export import export_run

    exported = export_run(Path(target), checkpoint=checkpoint, fmt=fmt,
                          output=Path(output) if output is not None else None)
    print(f"exported to {exported}")
    return exported


def export_sweep(sweep: str | Path, *, stage: str | None, output: str | Path | None, runs: str | Path = Path("runs"),
                 preset: str | None = None, seeds: Sequence[int] | None = None, models: Sequence[str] | None = None,
                 trials: int | None = None, device: str = "cpu", fmt: str = "onnx",
                 checkpoint: int | None = None) -> Path:
    """Ship the policies of a sweep's cells of `stage` into `output` with a manifest
    (`detach.runs.ship.ship_sweep`); returns the manifest's path."""
    if stage is None or output is None:
        raise ConfigError("exporting a sweep's policies needs --stage (e.g. lh1) and --output FOLDER", str(sweep))
    if fmt not in ("onnx", "policy") or checkpoint is not None:  # onnx: the default, not chosen
        raise ConfigError("a sweep's policies are exported as --format policy, each cell's own policy "
                          "(no --checkpoint)", str(sweep))
    from detach.runs.ship import ship_sweep

    manifest = ship_sweep(Path(sweep), Path(runs), Path(output), stage, preset=preset, seeds=seeds,
                          models=models or None, trials=trials, device=device)
    print(f"manifest written to {manifest}")
    return manifest


def play(target: str | Path, *, task: str | Path | None = None, device: str = "cpu", video: str | Path | None = None,
         episodes: int | None = None, steps: int | None = None, host: str = "127.0.0.1", port: int = 8081,
         size: tuple[int, int] = (640, 480)) -> int:
    """Watch a run's policy: in the live viewer (the `detach.viewers` entry point `live`, which
    the dashboard provides), or with `video` rendered to an mp4. Returns the control steps played
    live, or the video's frames."""
    check_device(device)
    run, checkpoint = run_and_checkpoint(Path(target))
    eval_task = task_path(task, "--task") if task else None
    if video is not None:
        _choose_gl()
        from detach.runs.play import play_video

        return play_video(run, checkpoint, eval_task, Path(video), device, episodes, steps, size)
    viewer = _live_viewer()
    from detach.runs.play import PolicyRollout

    rollout = PolicyRollout(run, checkpoint, eval_task, device)
    played = viewer(rollout, host, port, episodes, steps)
    print(f"played {played} steps ({rollout.episode} episodes ended)", flush=True)
    return played


def _live_viewer():
    """The live viewer, found by entry point: the dashboard sits above this package, which
    never imports it."""
    from importlib.metadata import entry_points

    found = [ep for ep in entry_points(group=VIEWER_ENTRY_POINTS) if ep.name == "live"]
    if not found:
        raise ConfigError(f"no live viewer installed (entry point '{VIEWER_ENTRY_POINTS}: live'; "
                          "pip install -e . installs the dashboard's); --video FILE.mp4 needs none")
    return found[0].load()


def sweep(sweep_file: str | Path, *, runs: str | Path = Path("runs"), jobs: int = 1, quick: bool = False,
          device: str = "cpu", launcher: str = "local", preset: str | None = None,
          models: Sequence[str] | None = None, seeds: Sequence[int] | None = None) -> int:
    """Run every unfinished cell of a sweep (`detach.runs.sweep.run_sweep`); returns how many failed."""
    check_device(device)
    from detach.runs.sweep import run_sweep

    return run_sweep(Path(sweep_file), Path(runs), jobs, quick, device, launcher=launcher, preset=preset,
                     models=models, seeds=seeds)
