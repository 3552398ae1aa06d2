"""Sweeps: the paper's experiments as graphs of runs that build on runs.

A sweep YAML (configs/sweeps/; `extends:` works as for tasks) names models, seeds and a list
of stages. A stage is a task trained for every model and seed, optionally starting from the
run of an earlier stage (`init_from: <stage>`: same model and seed; `train.init_from`), with
overrides; `eval` says on which tasks each stage's runs are evaluated. The two readings of the
paper's phase B (`phase_b: zero_shot | composition`, docs/PROTOCOL.md) select per-stage
overrides and model substitutions (`zero_shot:` / `composition:` in a stage). A preset
(`--preset NAME`, `--quick` = `--preset quick`) replaces seeds and trials, adds overrides, and
may give a stage's cells teachers (`stage_teachers`: per skill, the run of an earlier stage on
its `init_from` chain, or the scripted oracle; `train.teachers`) and add stages that continue
a stage (they take over its evaluations).

Every cell (stage x model x seed) is an ordinary run folder whose status.json carries the cell
key `<stage>/<model>/s<seed>/<digest>`; the digest covers everything that defines the run
(task, model, seed, overrides, presets, the parent and teacher cells), so sweeps that share a
stage (the phase-A runs of Tables I-III) share its runs. Re-running a sweep skips finished
cells, runs the evaluations a finished cell still lacks, and resumes interrupted or failed ones
from their last checkpoint. Cells run in dependency order on a local pool or as Ray tasks; a
lock per sweep file keeps two processes from running one sweep, and a lock per cell keeps two
sweeps from running one cell at the same time (the second waits for the first). Locks are `flock`s on
files under `<runs>/.locks/`: released when a process dies, and local to one machine unless the
runs folder's file system supports them across machines.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import json
import os
import signal
import subprocess
import sys
import tempfile
import threading
import time
from collections import deque
from concurrent.futures import FIRST_COMPLETED, Future, ThreadPoolExecutor, wait
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import BinaryIO, Collection, Iterable, Literal, Mapping, Sequence

from detach.config import find_config_file, load_merged, resolve
from detach.config_validate import Builder
from detach.eval.trial_sets import TrialSetError, check_test_offset
from detach.runfolder.names import eval_file
from detach.runfolder.folder import RunFolder, find_runs
from detach.runs.sweep_eta import SweepClock
from detach.skills import canonical_name
from detach.train.checkpoints import kept_iterations, saves_after
from detach.train.teachers import ORACLE
from detach.yaml_source import ConfigError

PhaseB = Literal["zero_shot", "composition"]


@dataclass(frozen=True)
class ReadingCfg:
    """What a stage changes under one reading of phase B."""

    overrides: tuple[str, ...] = ()
    models: dict[str, str] = field(default_factory=dict)
    """Model substitutions, e.g. {tokenhsi: tokenhsi_adapt}: the stage trains that model instead."""


@dataclass(frozen=True)
class StageCfg:
    name: str
    task: str
    """A task name in configs/tasks/ or a path relative to the sweep file."""
    init_from: str | None = None
    """An earlier stage: each run starts from that stage's run of the same model and seed."""
    overrides: tuple[str, ...] = ()
    zero_shot: ReadingCfg = ReadingCfg()
    composition: ReadingCfg = ReadingCfg()


@dataclass(frozen=True)
class PresetCfg:
    extends: str | None = None
    """Another preset of the sweep whose settings this one starts from (its own replace them;
    its overrides come after the base's)."""
    seeds: tuple[int, ...] | None = None
    eval_trials: int | None = None
    overrides: tuple[str, ...] = ()
    """Added to every cell."""
    stage_overrides: dict[str, tuple[str, ...]] = field(default_factory=dict)
    """Added to the cells of one stage (e.g. its iterations)."""
    stage_teachers: dict[str, dict[str, str]] = field(default_factory=dict)
    """Stage -> skill -> its teacher in that stage's cells (`train.teachers`): `oracle`, or a
    stage on the stage's `init_from` chain, whose run of the same model and seed teaches (it is
    finished before the cell starts, as the parent is)."""
    config_presets: tuple[str, ...] = ()
    """configs/presets/ files merged into every cell (`detach-run --preset`)."""
    phase_b: PhaseB | None = None
    """Replaces the sweep's reading of phase B."""
    stages: tuple[StageCfg, ...] = ()
    """Stages added after the sweep's, each continuing the stage it starts from (`init_from`,
    required): it takes over that stage's evaluations, so the tables read the continued policy
    (e.g. a second LH1 run taught by the first)."""


@dataclass(frozen=True)
class SweepCfg:
    name: str
    models: tuple[str, ...]
    stages: tuple[StageCfg, ...]
    seeds: tuple[int, ...] = (0,)
    phase_b: PhaseB = "zero_shot"
    overrides: tuple[str, ...] = ()
    eval: dict[str, tuple[str, ...]] = field(default_factory=dict)
    """Stage name -> tasks its runs are evaluated on (its own task writes eval.json)."""
    eval_trials: int = 100
    test_seed_offset: int | None = None
    """The held-out test trials of every cell (`detach.eval.trial_sets`): its evaluations play
    env seed = run seed + this and write eval.test.json; None: the development trials."""
    table: Literal["skills", "generalization", "ablation"] = "skills"
    presets: dict[str, PresetCfg] = field(default_factory=dict)
    preset: str | None = None
    """The preset applied (set by `load_sweep`, not in YAML)."""


@dataclass(frozen=True)
class Cell:
    stage: str
    task: Path
    model: str
    seed: int
    overrides: tuple[str, ...]
    presets: tuple[str, ...]
    parent: str | None
    """Key of the cell this one starts from."""
    evals: tuple[Path, ...]
    key: str
    teachers: tuple[tuple[str, str], ...] = ()
    """(skill, key of the ancestor cell that teaches it, or `oracle`)."""
    test_offset: int | None = None
    """The sweep's `test_seed_offset` (not part of the key: where a cell is evaluated does not
    change what it trains)."""

    @property
    def trial_set(self) -> str:
        return "development" if self.test_offset is None else "test"


def task_file(sweep_path: Path, name: str) -> Path:
    """`lh1` -> configs/tasks/lh1.yaml beside the sweep's folder (else found as `detach-run`
    finds a task name: the working directory's configs/, then detach's own); a path stays a path."""
    if name.endswith((".yaml", ".yml")):
        return (sweep_path.parent / name).resolve()
    beside = sweep_path.resolve().parent.parent / "tasks" / f"{name}.yaml"
    if beside.exists():
        return beside
    try:
        return find_config_file("tasks", name).resolve()
    except ConfigError:
        return beside  # the caller names the missing file with the sweep's file and line


def _require_task(builder: Builder, path: Path, where: tuple, task: str) -> None:
    """Refuse a task name of the sweep file `path` (at key `where`) that names no task file."""
    if not task_file(path, task).exists():
        raise builder.error(where, f"task '{task}' not found ({task_file(path, task)})")


def load_sweep(path: Path, quick: bool = False, preset: str | None = None,
               seeds: Sequence[int] | None = None) -> SweepCfg:
    """The sweep of `path` with `preset` applied (`quick` = preset "quick"), of `seeds` instead
    of its own when given."""
    data, prov = load_merged(Path(path))
    builder = Builder(prov, str(path))
    sweep = builder.build(SweepCfg, data, ())
    names = [s.name for s in sweep.stages]
    if len(set(names)) != len(names):
        raise ConfigError(f"stage names must be unique, found {names}", str(path))
    for i, stage in enumerate(sweep.stages):
        if stage.init_from is not None and stage.init_from not in names[:i]:
            raise builder.error(("stages", i, "init_from"),
                                f"expected an earlier stage ({', '.join(names[:i]) or 'none'}), "
                                f"found {stage.init_from!r}")
        _require_task(builder, path, ("stages", i, "task"), stage.task)
    for stage_name, tasks in sweep.eval.items():
        if stage_name not in names:
            raise builder.error(("eval", stage_name), f"unknown stage; stages: {', '.join(names)}")
        for task in tasks:
            _require_task(builder, path, ("eval", stage_name), task)
    if sweep.test_seed_offset is not None:
        try:
            check_test_offset(sweep.test_seed_offset)
        except TrialSetError as exc:
            raise builder.error(("test_seed_offset",), str(exc)) from None
    preset = "quick" if quick and preset is None else preset
    if preset is not None:
        if preset not in sweep.presets:
            raise ConfigError(f"sweep '{sweep.name}' has no preset '{preset}'; presets: "
                              f"{', '.join(sweep.presets) or 'none'}", str(path))
        p = _resolved_preset(sweep, preset, builder)
        sweep = _with_added_stages(sweep, preset, builder, path)
        names = [s.name for s in sweep.stages]
        unknown = [s for s in p.stage_overrides if s not in names]
        if unknown:
            raise builder.error(("presets", preset, "stage_overrides", unknown[0]), "unknown stage")
        _check_teachers(sweep, p, preset, builder)
        sweep = replace(sweep, seeds=p.seeds or sweep.seeds, eval_trials=p.eval_trials or sweep.eval_trials,
                        overrides=(*sweep.overrides, *p.overrides), phase_b=p.phase_b or sweep.phase_b,
                        presets={**sweep.presets, preset: p}, preset=preset)
    return sweep if seeds is None else replace(sweep, seeds=tuple(seeds))


def _with_added_stages(sweep: SweepCfg, preset: str, builder: Builder, path: Path) -> SweepCfg:
    """The sweep with the stages of `preset` and of the presets it extends (base first) added,
    each taking over the evaluations of the stage it continues."""
    chain, at = [], preset
    while at is not None:  # `_resolved_preset` has refused loops already
        chain.append(at)
        at = sweep.presets[at].extends
    stages, evals = list(sweep.stages), dict(sweep.eval)
    for name in reversed(chain):
        for i, stage in enumerate(sweep.presets[name].stages):
            where = ("presets", name, "stages", i)
            names = [s.name for s in stages]
            if stage.name in names:
                raise builder.error((*where, "name"), f"expected a new stage name, found {stage.name!r} (stages: "
                                                      f"{', '.join(names)})")
            if stage.init_from not in names:
                raise builder.error((*where, "init_from"),
                                    f"expected the stage this one continues ({', '.join(names)}), "
                                    f"found {stage.init_from!r}")
            _require_task(builder, path, (*where, "task"), stage.task)
            stages.append(stage)
            evals[stage.name] = evals.pop(stage.init_from, ())
    return replace(sweep, stages=tuple(stages), eval=evals)


def _ancestors(sweep: SweepCfg, stage: str) -> list[str]:
    """The stages on `stage`'s `init_from` chain, nearest first."""
    by_name = {s.name: s for s in sweep.stages}
    chain, at = [], by_name[stage].init_from
    while at is not None:
        chain.append(at)
        at = by_name[at].init_from
    return chain


def _check_teachers(sweep: SweepCfg, preset: PresetCfg, name: str, builder: Builder) -> None:
    """Each stage teacher names a stage of the sweep, a skill, and `oracle` or an ancestor stage."""
    for stage, teachers in preset.stage_teachers.items():
        where = ("presets", name, "stage_teachers", stage)
        if stage not in {s.name for s in sweep.stages}:
            raise builder.error(where, "unknown stage")
        ancestors = _ancestors(sweep, stage)
        for skill, source in teachers.items():
            try:
                canonical_name(skill)
            except ValueError as exc:
                raise builder.error((*where, skill), str(exc)) from None
            if source != ORACLE and source not in ancestors:
                raise builder.error((*where, skill), f"expected '{ORACLE}' or a stage on {stage}'s init_from chain "
                                                     f"({', '.join(ancestors) or 'none'}), found {source!r}")


def _resolved_preset(sweep: SweepCfg, name: str, builder: Builder, seen: tuple[str, ...] = ()) -> PresetCfg:
    """The preset `name` with its `extends` chain merged in."""
    p = sweep.presets[name]
    if p.extends is None:
        return p
    if p.extends not in sweep.presets or p.extends in (*seen, name):
        raise builder.error(("presets", name, "extends"), f"expected another preset of this sweep "
                            f"({', '.join(k for k in sweep.presets if k != name)}), found {p.extends!r}")
    base = _resolved_preset(sweep, p.extends, builder, (*seen, name))
    return PresetCfg(None, p.seeds or base.seeds, p.eval_trials or base.eval_trials, (*base.overrides, *p.overrides),
                     {**base.stage_overrides,
                      **{k: (*base.stage_overrides.get(k, ()), *v) for k, v in p.stage_overrides.items()}},
                     {**base.stage_teachers,
                      **{k: {**base.stage_teachers.get(k, {}), **v} for k, v in p.stage_teachers.items()}},
                     (*base.config_presets, *p.config_presets),
                     p.phase_b or base.phase_b)  # stages: `_with_added_stages`


def _digest(parts: dict) -> str:
    return hashlib.sha1(json.dumps(parts, sort_keys=True).encode()).hexdigest()[:10]


def cells(sweep: SweepCfg, sweep_path: Path) -> list[Cell]:
    """Every cell of the sweep, parents before children."""
    preset = sweep.presets.get(sweep.preset) if sweep.preset else None
    out: dict[tuple[str, str, int], Cell] = {}
    for stage in sweep.stages:
        reading = getattr(stage, sweep.phase_b)
        task = task_file(sweep_path, stage.task)
        for model in sweep.models:
            for seed in sweep.seeds:
                parent = out[(stage.init_from, model, seed)] if stage.init_from else None
                overrides = (*sweep.overrides, *stage.overrides, *reading.overrides,
                             *(preset.stage_overrides.get(stage.name, ()) if preset else ()))
                presets = preset.config_presets if preset else ()
                trained = reading.models.get(model, model)
                named = preset.stage_teachers.get(stage.name, {}) if preset else {}
                teachers = tuple((skill, source if source == ORACLE else out[(source, model, seed)].key)
                                 for skill, source in named.items())
                defining = {"task": task.name, "model": trained, "seed": seed, "overrides": list(overrides),
                            "presets": list(presets), "parent": parent.key if parent else None}
                if teachers:  # only then: the digests of cells without teachers stay what they were
                    defining["teachers"] = [list(t) for t in teachers]
                evals = tuple(task_file(sweep_path, t) for t in sweep.eval.get(stage.name, ()))
                out[(stage.name, model, seed)] = Cell(stage.name, task, trained, seed, overrides, presets,
                                                      parent.key if parent else None, evals,
                                                      f"{stage.name}/{trained}/s{seed}/{_digest(defining)}", teachers,
                                                      sweep.test_seed_offset)
    return list(out.values())


def cell_evaluations(sweep_path: Path, preset: str | None = None,
                     seeds: Sequence[int] | None = None) -> dict[str, frozenset[str]]:
    """Key of each of the sweep's cells under `preset` (None = its default settings; of
    `seeds` instead of its own when given) -> the tasks the sweep evaluates it on: what a
    table of that sweep reads, so neither runs of another preset or reading nor evaluations
    made by hand on other tasks (a phase-A policy tried on LH1) pool into it."""
    sweep = load_sweep(sweep_path, preset=preset, seeds=seeds)
    return {c.key: frozenset(t.stem for t in c.evals) for c in cells(sweep, sweep_path)}


def existing_runs(out: Path) -> dict[str, RunFolder]:
    """Newest run folder per cell key."""
    found: dict[str, RunFolder] = {}
    for run in find_runs(out):
        try:
            key = run.status().cell
        except (OSError, ValueError):
            continue
        if key:
            found[key] = run
    return found


# ------------------------------------------------------------------------------- commands
def _missing_evals(cell: Cell, run: RunFolder) -> list[Path]:
    """Evaluation tasks of the cell whose eval file the run does not have yet."""
    return [t for t in cell.evals
            if not (run.path / eval_file(None if t.stem == cell.task.stem else t.stem, cell.trial_set)).exists()]


def cell_commands(cell: Cell, previous: RunFolder | None, parent: RunFolder | None, out: Path,
                  trials: int, device: str, teachers: dict[str, RunFolder] | None = None) -> list[list[str]]:
    """The `detach-run` calls that bring the cell to done: none when it is finished and fully
    evaluated; evaluations only when it is finished; else a resume or a new run (`teachers`:
    the run of each teacher cell, by key; a resumed run keeps the teachers its config pinned)."""
    python = [sys.executable, "-m", "detach.cli"]
    own = any(t.stem == cell.task.stem for t in cell.evals)
    others = [arg for t in cell.evals if t.stem != cell.task.stem for arg in ("--eval-on", str(t))]
    common = ["--trials", str(trials), "--device", device,
              *(["--test-trials", str(cell.test_offset)] if cell.test_offset is not None else [])]
    if previous is not None:
        state = previous.status().state
        if state == "finished":
            return [[*python, "--eval", str(previous.path), "--task", str(t), *common]
                    for t in _missing_evals(cell, previous)]
        if previous.latest_checkpoint() is not None:
            return [[*python, "--resume", str(previous.path), *common, *others, *([] if own else ["--no-eval"])]]
    init = [f"train.init_from={parent.path.resolve()}"] if parent is not None else []
    taught = []
    for skill, source in cell.teachers:
        if source != ORACLE and (teachers is None or source not in teachers):
            raise ConfigError(f"cell {cell.key}: its {skill} teacher, cell {source}, has no run in {out}")
        taught.append(f"+train.teachers.{skill}={source if source == ORACLE else teachers[source].path.resolve()}")
    presets = [arg for p in cell.presets for arg in ("--preset", p)]
    return [[*python, str(cell.task), "--model", cell.model, "--seed", str(cell.seed), "--runs", str(out),
             "--cell", cell.key, *presets, *common, *others, *([] if own else ["--no-eval"]),
             *cell.overrides, *init, *taught]]


# ------------------------------------------------------------------------------- locks
@contextlib.contextmanager
def file_lock(path: Path, wait_s: float | None = 0.0):
    """An exclusive `flock` on `path`; yields True when held, False when another process holds
    it (after waiting `wait_s` seconds; None waits for ever)."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with open(path, "a+") as handle:
        deadline = None if wait_s is None else time.monotonic() + wait_s
        while True:
            try:
                fcntl.flock(handle, fcntl.LOCK_EX | fcntl.LOCK_NB)
                break
            except BlockingIOError:
                if deadline is not None and time.monotonic() >= deadline:
                    yield False
                    return
                time.sleep(1.0)
        handle.seek(0)
        handle.truncate()
        handle.write(f"{os.getpid()}\n")
        handle.flush()
        try:
            yield True
        finally:
            fcntl.flock(handle, fcntl.LOCK_UN)


def _lock_path(out: Path, name: str) -> Path:
    return out / ".locks" / f"{hashlib.sha1(name.encode()).hexdigest()[:16]}.lock"


# ------------------------------------------------------------------------------- running
_CHILDREN: set[subprocess.Popen] = set()
"""Cell processes of this sweep now running: a stopped sweep passes its SIGTERM on to them."""
_STOPPING = threading.Event()


def _run_command(cmd: list[str], cwd: str, env: dict[str, str] | None = None) -> tuple[int, str]:
    """(exit code, the last lines of stderr)."""
    if _STOPPING.is_set():
        from detach.runs.job import EXIT_INTERRUPTED

        return EXIT_INTERRUPTED, "the sweep was stopped"
    with tempfile.TemporaryFile("w+b") as err:  # a file, not a pipe: hours of progress bar stay on disk
        proc = subprocess.Popen(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        _CHILDREN.add(proc)
        try:
            proc.wait()
        finally:
            _CHILDREN.discard(proc)
        return proc.returncode, stderr_tail(err)


TAIL_LINES = 15
"""Lines of a failed cell's stderr that the sweep prints."""


def stderr_tail(err: BinaryIO, lines: int = TAIL_LINES, max_bytes: int = 64 * 1024) -> str:
    """The last `lines` lines of a stderr file, each line as a terminal would show it (a
    progress bar's carriage returns keep only its last state)."""
    err.seek(0, os.SEEK_END)
    size = err.tell()
    err.seek(max(0, size - max_bytes))
    text = err.read().decode("utf-8", "replace")
    shown = [line.rstrip("\r").rsplit("\r", 1)[-1].rstrip() for line in text.split("\n")]
    return "\n".join([line for line in shown if line][-lines:])


def _stop_children() -> None:
    """SIGTERM to every running cell (each checkpoints and ends `interrupted`); no new cell or
    command starts. Ctrl-C reaches the cells by itself (same process group); SIGTERM does not."""
    _STOPPING.set()
    for proc in list(_CHILDREN):
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)


def _cell_env(jobs: int) -> dict[str, str]:
    """Parallel cells share the cores: each torch gets cores // jobs threads (torch reads
    OMP_NUM_THREADS for its default) unless the user has set it."""
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // max(jobs, 1))))
    return env


def _runs_alone(cell: Cell, running: Collection[Cell], pending: Iterable[Cell], by_key: Mapping[str, Cell]) -> bool:
    """Nothing else of the sweep can run while `cell` does: none is running and every cell
    still to run starts from it (directly or further down). Such a cell gets every core: the
    thread count is fixed when a cell starts, and with `--jobs 2` the sweep's last cells ran
    on one torch thread beside an idle core (DETACH's Carry and LH1, 17 minutes of Table I)."""
    def descends(other: Cell) -> bool:
        at = other.parent
        while at is not None:
            if at == cell.key:
                return True
            at = by_key[at].parent if at in by_key else None
        return False

    return not running and all(descends(other) for other in pending)


class _LocalPool:
    def __init__(self, jobs: int) -> None:
        self.pool = ThreadPoolExecutor(max_workers=max(jobs, 1))
        self.jobs = jobs

    def submit(self, work: "_Work") -> Future:
        return self.pool.submit(work)

    def close(self) -> None:
        self.pool.shutdown(wait=True)


class _RayPool:
    """Each cell's commands as one Ray task (one CPU). Joins the cluster of `RAY_ADDRESS` if
    set, else starts a local Ray with `jobs` CPUs. On a cluster, the runs folder must be a file
    system every node sees and the project installed on every node."""

    def __init__(self, jobs: int) -> None:
        try:
            import ray
        except ImportError:
            raise ConfigError("--launcher ray needs Ray: pip install 'detach[ray]'") from None
        self.ray = ray
        if not ray.is_initialized():
            address = os.environ.get("RAY_ADDRESS")
            ray.init(address=address, num_cpus=None if address else max(jobs, 1),
                     include_dashboard=False, log_to_driver=False)
        self.remote = ray.remote(num_cpus=1)(_run_commands)
        self.jobs = jobs

    def submit(self, work: "_Work") -> Future:
        """The cell's commands, decided here, run remotely (no cell lock: Ray runs each cell of
        this sweep once, and another process's sweep is kept out by the sweep lock only)."""
        future: Future = Future()
        future.ref = self.remote.remote(work.commands(), work.cwd)  # type: ignore[attr-defined]
        return future

    def resolve(self, futures: set[Future]) -> None:
        """Complete the futures whose Ray tasks finished, as they finish (`ray.wait` for the
        first, then every other one already done); a task that died is a failed cell."""
        pending = {f.ref: f for f in futures if not f.done()}  # type: ignore[attr-defined]
        if not pending:
            return
        ready, rest = self.ray.wait(list(pending), num_returns=1, timeout=1.0)
        if ready and rest:
            more, _ = self.ray.wait(rest, num_returns=len(rest), timeout=0)
            ready = [*ready, *more]
        for ref in ready:
            try:
                result = self.ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - the worker died or the task raised
                result = (1, f"Ray task failed: {type(exc).__name__}: {exc}")
            pending[ref].set_result(result)

    def close(self) -> None:
        """Ray stays up for other sweeps of this process."""


class _SubmititPool:
    """Each cell's commands as one SLURM job through submitit (the [slurm] extra). The
    executor is submitit's `AutoExecutor` (SLURM where `sbatch` exists, else local processes);
    `DETACH_SUBMITIT_CLUSTER` forces one of submitit's clusters (`slurm`, `local`, `debug`) and
    `DETACH_SUBMITIT` holds the executor's parameters as JSON (e.g. {"slurm_partition": "gpu",
    "timeout_min": 1440, "gpus_per_node": 1, "cpus_per_task": 16}). Job logs go to
    <runs>/.submitit/. As with Ray, the runs folder and the project must be on every node."""

    def __init__(self, jobs: int, out: Path) -> None:
        try:
            import submitit
        except ImportError:
            raise ConfigError("--launcher slurm needs submitit: pip install 'detach[slurm]'") from None
        try:
            params = json.loads(os.environ.get("DETACH_SUBMITIT", "{}") or "{}")
        except json.JSONDecodeError as exc:
            raise ConfigError(f"DETACH_SUBMITIT: not JSON ({exc})") from None
        if not isinstance(params, dict):
            raise ConfigError("DETACH_SUBMITIT: expected a JSON object of executor parameters")
        self.folder = out / ".submitit"
        self.executor = submitit.AutoExecutor(folder=self.folder,
                                              cluster=os.environ.get("DETACH_SUBMITIT_CLUSTER") or None)
        params.setdefault("timeout_min", 7 * 24 * 60)
        params.setdefault("name", "detach-sweep")
        try:
            self.executor.update_parameters(**params)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"DETACH_SUBMITIT: {exc}") from None
        self.jobs = jobs
        self.submitted: list = []

    def submit(self, work: "_Work") -> Future:
        """The cell's commands, decided here, run as one job (no cell lock, as with Ray)."""
        future: Future = Future()
        future.job = self.executor.submit(_run_commands, work.commands(), work.cwd)  # type: ignore[attr-defined]
        self.submitted.append(future.job)  # type: ignore[attr-defined]
        return future

    def resolve(self, futures: set[Future]) -> None:
        """Complete the futures whose jobs ended (polled; a job that died is a failed cell
        with the tail of its log)."""
        ended = False
        for future in futures:
            job = future.job  # type: ignore[attr-defined]
            if future.done() or not job.done():
                continue
            ended = True
            try:
                future.set_result(job.result())
            except Exception as exc:  # noqa: BLE001 - the job failed or was cancelled
                log = (job.stderr() or "") if hasattr(job, "stderr") else ""
                lines = [line for line in log.splitlines() if line.strip()][-TAIL_LINES:]
                future.set_result((1, "\n".join([f"job {job.job_id} failed: {type(exc).__name__}", *lines])))
        if not ended:
            time.sleep(1.0)

    def close(self) -> None:
        """Jobs that still run are the scheduler's (a stopped sweep cancels them first)."""

    def cancel(self) -> None:
        """Cancel the jobs of this sweep that have not ended (Ctrl-C / SIGTERM of the sweep:
        SLURM sends them SIGTERM, and each run checkpoints and ends `interrupted`)."""
        for job in self.submitted:
            if not job.done():
                with contextlib.suppress(Exception):
                    job.cancel(check=False)


def _run_commands(cmds: list[list[str]], cwd: str, env: dict[str, str] | None = None) -> tuple[int, str]:
    for cmd in cmds:
        code, tail = _run_command(cmd, cwd, env)
        if code != 0:
            return code, tail
    return 0, ""


OWNER_POLL_S = 5.0
"""How often a sweep looks again at a cell that another live process is training."""


@dataclass
class _Work:
    """A callable running one cell under its lock (attributes for the Ray launcher)."""

    cell: Cell
    out: Path
    trials: int
    device: str
    env: dict[str, str]
    cwd: str = field(default_factory=os.getcwd)

    def commands(self) -> list[list[str]]:
        """What brings the cell to done, decided once no other live process owns its run. The
        cell lock does not cover every owner (a sweep whose driver was killed leaves its cell
        training; a run started by hand with --cell; Ray and Slurm sweeps take no cell lock):
        starting it again would train it twice, resuming it would be refused as alive."""
        said = False
        while True:
            runs = existing_runs(self.out)  # re-read: another sweep may have run the cell meanwhile
            previous = runs.get(self.cell.key)
            if previous is None or _STOPPING.is_set() or not previous.owner_alive():
                break
            if not said:
                status = previous.status()
                where = f" on {status.host}" if status.host else ""
                print(f"waiting: {self.cell.key} is running in process {status.pid}{where} "
                      f"({previous.path})", flush=True)
                said = True
            time.sleep(OWNER_POLL_S)
        parent = runs.get(self.cell.parent) if self.cell.parent else None
        teachers = {key: runs[key] for _, key in self.cell.teachers if key in runs}
        return cell_commands(self.cell, runs.get(self.cell.key), parent, self.out, self.trials, self.device, teachers)

    def __call__(self) -> tuple[int, str]:
        """Run the cell under its lock: a second sweep that reaches it waits, then finds it done."""
        with file_lock(_lock_path(self.out, self.cell.key), wait_s=None):
            return _run_commands(self.commands(), self.cwd, self.env)


def cell_work(cell: Cell, trials: int) -> float | None:
    """Env steps the cell simulates: its training samples plus, at full episode length, its
    evaluations' trials and the validation trials of its choices (the start's
    `init_action_mean_choices`, and each checkpoint it keeps under `select_checkpoint_trials`).
    None when its config does not resolve; the run will say why."""
    try:
        cfg = resolve(cell.task, cell.model, cell.overrides, seed=cell.seed, presets=cell.presets)
    except (ConfigError, OSError):
        return None
    t = cfg.train
    samples = t.max_iterations * t.num_steps_per_env * cfg.sim.num_envs
    episodes = len(cell.evals) * trials + len(t.init_action_mean_choices) * t.init_choice_trials
    if t.select_checkpoint_trials:
        saved = [it for it in range(t.max_iterations) if saves_after(it, t.max_iterations, t.save_interval)]
        kept = kept_iterations(saved, t.keep_checkpoints.last, t.keep_checkpoints.every)
        episodes += len(kept) * t.select_checkpoint_trials
    return float(samples + episodes * cfg.env.episode_length)


def run_sweep(sweep_path: Path, out: Path, jobs: int = 1, quick: bool = False, device: str = "cpu",
              launcher: str = "local", preset: str | None = None, models: Sequence[str] | None = None,
              seeds: Sequence[int] | None = None) -> int:
    """Run every cell that is not finished and evaluated (of `models` only, and of `seeds`
    instead of the sweep's, when given); returns the number that failed."""
    sweep = load_sweep(sweep_path, quick, preset, seeds)
    if models:
        unknown = [m for m in models if m not in sweep.models]
        if unknown:
            raise ConfigError(f"--models: {unknown[0]!r} is not a model of sweep '{sweep.name}' "
                              f"({', '.join(sweep.models)})", str(sweep_path))
        sweep = replace(sweep, models=tuple(m for m in sweep.models if m in models))
    label = (f"{sweep.name}" + (f" [{sweep.preset}]" if sweep.preset else "")
             + (f" {{{','.join(models)}}}" if models else "")
             + (f" seeds {','.join(map(str, sweep.seeds))}" if seeds is not None else ""))
    lock = f"sweep:{Path(sweep_path).resolve()}:{sweep.preset}:{sweep.models}:{sweep.seeds}"
    with file_lock(_lock_path(out, lock)) as held:
        if not held:
            raise ConfigError(f"sweep {label} is already running in another process (lock in {out}/.locks)",
                              str(sweep_path))
        return _run_graph(sweep, sweep_path, out, jobs, device, launcher, label)


def _run_graph(sweep: SweepCfg, sweep_path: Path, out: Path, jobs: int, device: str, launcher: str,
               label: str) -> int:
    todo = cells(sweep, sweep_path)
    runs = existing_runs(out)
    done_keys = {c.key for c in todo if _complete(c, runs.get(c.key))}
    pending = deque(c for c in todo if c.key not in done_keys)
    total = len(pending)
    print(f"sweep {label}: {len(todo)} cells, {len(done_keys)} done, {total} to run with {jobs} job(s) "
          f"({launcher}), phase B: {sweep.phase_b}", flush=True)
    if not pending:
        return 0
    pool = _RayPool(jobs) if launcher == "ray" else _SubmititPool(jobs, out) if launcher == "slurm" \
        else _LocalPool(jobs)
    env, env_alone = _cell_env(jobs), _cell_env(1)
    by_key = {c.key: c for c in todo}
    running: dict[Future, Cell] = {}
    failed: set[str] = set()
    finished = 0
    clock = SweepClock(jobs)
    for cell in pending:
        clock.add(cell.key, cell_work(cell, sweep.eval_trials))
    try:
        while pending or running:
            for cell in list(pending):
                if len(running) >= max(jobs, 1):
                    break
                if cell.parent in failed:
                    pending.remove(cell)
                    failed.add(cell.key)
                    finished += 1
                    clock.skip(cell.key)
                    print(f"[{finished}/{total}] {cell.key}: SKIPPED (its parent cell failed)", flush=True)
                elif cell.parent is None or cell.parent in done_keys:
                    pending.remove(cell)
                    cell_env = env_alone if _runs_alone(cell, running.values(), pending, by_key) else env
                    running[pool.submit(_Work(cell, out, sweep.eval_trials, device, cell_env))] = cell
                    clock.start(cell.key)
                    print(f"[{finished}/{total}] {cell.key}: start ({clock.progress()})",
                          flush=True)
            if not running:
                break
            if isinstance(pool, (_RayPool, _SubmititPool)):
                pool.resolve(set(running))
                ready = {f for f in running if f.done()}
            else:
                ready, _ = wait(set(running), timeout=5.0, return_when=FIRST_COMPLETED)
            for future in ready:
                cell = running.pop(future)
                code, tail = future.result()
                finished += 1
                clock.end(cell.key)
                if code == 0:
                    done_keys.add(cell.key)
                    print(f"[{finished}/{total}] {cell.key}: done ({clock.progress()})",
                          flush=True)
                else:
                    failed.add(cell.key)
                    print(f"[{finished}/{total}] {cell.key}: FAILED (exit {code}; "
                          f"{clock.progress()})"
                          + "".join(f"\n    | {line}" for line in tail.splitlines()), flush=True)
    except KeyboardInterrupt:  # Ctrl-C or SIGTERM (detach.cli turns SIGTERM into KeyboardInterrupt)
        _stop_children()
        if isinstance(pool, _SubmititPool):
            pool.cancel()
        raise
    finally:
        pool.close()
    return len(failed)


def _complete(cell: Cell, run: RunFolder | None) -> bool:
    """Finished and evaluated on every task the sweep asks for."""
    if run is None:
        return False
    try:
        state = run.status().state
    except (OSError, ValueError):
        return False
    return state == "finished" and not _missing_evals(cell, run)


__all__ = ["Cell", "SweepCfg", "cell_evaluations", "cell_commands", "cells", "load_sweep", "run_sweep"]
