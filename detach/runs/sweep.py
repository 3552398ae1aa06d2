"""Sweeps: the paper's experiments as grids of tasks x models x seeds.

A sweep YAML (configs/sweeps/) names training tasks, models, seeds, overrides shared by all
cells, the tasks each trained policy is evaluated on and the table it fills; a `quick` preset
(`--quick`) replaces seeds/overrides/trials for a CPU smoke run. Every cell is an ordinary run
folder whose status.json carries the cell key; re-running a sweep skips finished cells and
resumes interrupted or failed ones. Cells run as `detach-run` subprocesses on a local pool.
"""

from __future__ import annotations

import os
import subprocess
import sys
from concurrent.futures import ThreadPoolExecutor
from dataclasses import dataclass, replace
from pathlib import Path
from typing import Literal

from detach.config_validate import Builder
from detach.runs.folder import RunFolder, find_runs
from detach.yaml_source import ConfigError, load_yaml


@dataclass(frozen=True)
class QuickCfg:
    seeds: tuple[int, ...] | None = None
    overrides: tuple[str, ...] = ()
    eval_trials: int | None = None


@dataclass(frozen=True)
class SweepCfg:
    name: str
    tasks: tuple[str, ...]
    """Training tasks: names in configs/tasks/ or paths relative to the sweep file."""
    models: tuple[str, ...]
    seeds: tuple[int, ...] = (0,)
    overrides: tuple[str, ...] = ()
    eval_tasks: tuple[str, ...] = ()
    """Tasks every trained policy is evaluated on; empty = its training task only."""
    eval_trials: int = 100
    table: Literal["skills", "generalization", "ablation"] = "skills"
    quick: QuickCfg = QuickCfg()


@dataclass(frozen=True)
class Cell:
    task: Path
    model: str
    seed: int
    key: str


def load_sweep(path: Path, quick: bool = False) -> SweepCfg:
    data, prov = load_yaml(path)
    sweep = Builder(prov, str(path)).build(SweepCfg, data, ())
    for name in (*sweep.tasks, *sweep.eval_tasks):
        if not task_file(path, name).exists():
            raise ConfigError(f"task '{name}' not found ({task_file(path, name)})", str(path))
    if quick:
        q = sweep.quick
        sweep = replace(sweep, seeds=q.seeds or sweep.seeds,
                        overrides=(*sweep.overrides, *q.overrides),
                        eval_trials=q.eval_trials or sweep.eval_trials)
    return sweep


def task_file(sweep_path: Path, name: str) -> Path:
    """`lh1` -> configs/tasks/lh1.yaml beside the sweep's folder; a path stays a path."""
    if name.endswith((".yaml", ".yml")):
        return (sweep_path.parent / name).resolve()
    return (sweep_path.resolve().parent.parent / "tasks" / f"{name}.yaml")


def cells(sweep: SweepCfg, sweep_path: Path) -> list[Cell]:
    return [Cell(task_file(sweep_path, t), m, s, f"{sweep.name}/{Path(t).stem}/{m}/s{s}")
            for t in sweep.tasks for m in sweep.models for s in sweep.seeds]


def existing_runs(out: Path) -> dict[str, RunFolder]:
    """Newest run folder per sweep cell key."""
    found: dict[str, RunFolder] = {}
    for run in find_runs(out):
        try:
            key = run.status().cell
        except (OSError, ValueError):
            continue
        if key:
            found[key] = run
    return found


def cell_command(cell: Cell, sweep: SweepCfg, sweep_path: Path, out: Path,
                 device: str, previous: RunFolder | None) -> list[str] | None:
    """The detach-run call for a cell, or None when it is already finished."""
    evals = [str(task_file(sweep_path, t)) for t in sweep.eval_tasks]
    common = ["--trials", str(sweep.eval_trials), "--device", device]
    common += [arg for t in evals for arg in ("--eval-on", t)]
    if previous is not None:
        state = previous.status().state
        if state == "finished":
            return None
        if state in ("interrupted", "failed", "running") and previous.latest_checkpoint():
            return [sys.executable, "-m", "detach.cli", "--resume", str(previous.path), *common]
    return [sys.executable, "-m", "detach.cli", str(cell.task), "--model", cell.model,
            "--seed", str(cell.seed), "--out", str(out), "--cell", cell.key, *common,
            *sweep.overrides]


def _run_command(cmd: list[str], cwd: str, env: dict[str, str] | None = None) -> int:
    return subprocess.run(cmd, cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                          text=True).returncode


def _cell_env(jobs: int) -> dict[str, str]:
    """Parallel cells share the cores: each torch gets cores // jobs threads (torch reads
    OMP_NUM_THREADS for its default) unless the user has set it."""
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // max(jobs, 1))))
    return env


def _launch_local(pending: list[tuple[Cell, list[str]]], jobs: int) -> list[int]:
    def launch(item: tuple[Cell, list[str]]) -> int:
        cell, cmd = item
        print(f"[{cell.key}] start", flush=True)
        code = _run_command(cmd, os.getcwd(), _cell_env(jobs))
        print(f"[{cell.key}] {'done' if code == 0 else f'FAILED (exit {code})'}", flush=True)
        return code

    with ThreadPoolExecutor(max_workers=max(jobs, 1)) as pool:
        return list(pool.map(launch, pending))


def _launch_ray(pending: list[tuple[Cell, list[str]]], jobs: int) -> list[int]:
    """Each cell as a Ray task (one CPU each) running the same `detach-run` command.

    Joins the cluster of `RAY_ADDRESS` if set, else starts a local Ray with `jobs` CPUs.
    On a real cluster, `--out` must be a filesystem every node sees and the project must be
    installed on every node (the command uses the driver's Python path).
    """
    try:
        import ray
    except ImportError:
        raise ConfigError("--launcher ray needs Ray: pip install 'detach[ray]'") from None
    if not ray.is_initialized():
        address = os.environ.get("RAY_ADDRESS")
        ray.init(address=address, num_cpus=None if address else max(jobs, 1),
                 include_dashboard=False, log_to_driver=False)
    remote = ray.remote(num_cpus=1)(_run_command)
    refs = [remote.remote(cmd, os.getcwd()) for _cell, cmd in pending]
    for cell, _cmd in pending:
        print(f"[{cell.key}] submitted", flush=True)
    codes = ray.get(refs)
    for (cell, _cmd), code in zip(pending, codes):
        print(f"[{cell.key}] {'done' if code == 0 else f'FAILED (exit {code})'}", flush=True)
    return codes


LAUNCHERS = {"local": _launch_local, "ray": _launch_ray}


def run_sweep(sweep_path: Path, out: Path, jobs: int = 1, quick: bool = False,
              device: str = "cpu", launcher: str = "local") -> int:
    """Run every unfinished cell; returns the number of cells that failed."""
    sweep = load_sweep(sweep_path, quick)
    done = existing_runs(out)
    todo = [(c, cell_command(c, sweep, sweep_path, out, device, done.get(c.key)))
            for c in cells(sweep, sweep_path)]
    pending = [(c, cmd) for c, cmd in todo if cmd is not None]
    print(f"sweep {sweep.name}: {len(todo)} cells, {len(todo) - len(pending)} finished, "
          f"{len(pending)} to run with {jobs} job(s) ({launcher})")

    codes = LAUNCHERS[launcher](pending, jobs) if pending else []
    return sum(1 for code in codes if code != 0)
