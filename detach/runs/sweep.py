"""Sweeps: the paper's experiments as grids of tasks x models x seeds.

A sweep YAML (configs/sweeps/) names training tasks, models, seeds, overrides shared by all
cells, the tasks each trained policy is evaluated on and the table it fills; a `quick` preset
(`--quick`) replaces seeds/overrides/trials for a CPU smoke run. Every cell is an ordinary run
folder whose status.json carries the cell key; re-running a sweep skips finished cells and
resumes interrupted or failed ones. Cells run as `detach-run` subprocesses on a local pool.
"""

from __future__ import annotations

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
            key = run.status().get("cell")
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
        state = previous.status().get("state")
        if state == "finished":
            return None
        if state in ("interrupted", "failed", "running") and previous.latest_checkpoint():
            return [sys.executable, "-m", "detach.cli", "--resume", str(previous.path), *common]
    return [sys.executable, "-m", "detach.cli", str(cell.task), "--model", cell.model,
            "--seed", str(cell.seed), "--out", str(out), "--cell", cell.key, *common,
            *sweep.overrides]


def run_sweep(sweep_path: Path, out: Path, jobs: int = 1, quick: bool = False,
              device: str = "cpu") -> int:
    """Run every unfinished cell; returns the number of cells that failed."""
    sweep = load_sweep(sweep_path, quick)
    done = existing_runs(out)
    todo = [(c, cell_command(c, sweep, sweep_path, out, device, done.get(c.key)))
            for c in cells(sweep, sweep_path)]
    pending = [(c, cmd) for c, cmd in todo if cmd is not None]
    print(f"sweep {sweep.name}: {len(todo)} cells, {len(todo) - len(pending)} finished, "
          f"{len(pending)} to run with {jobs} job(s)")

    def launch(item: tuple[Cell, list[str]]) -> tuple[Cell, int]:
        cell, cmd = item
        print(f"[{cell.key}] start", flush=True)
        code = subprocess.run(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.PIPE,
                              text=True).returncode
        print(f"[{cell.key}] {'done' if code == 0 else f'FAILED (exit {code})'}", flush=True)
        return cell, code

    with ThreadPoolExecutor(max_workers=max(jobs, 1)) as pool:
        results = list(pool.map(launch, pending))
    return sum(1 for _c, code in results if code != 0)
