"""Sweeps: the paper's experiments as graphs of runs that build on runs, run to done.

The sweep file is read by `detach.runs.sweep_config` and made a graph of cells by
`detach.runs.sweep_graph`. Re-running a sweep skips finished cells, runs the evaluations a
finished cell still lacks, and resumes interrupted or failed ones from their last checkpoint
(`detach.runs.sweep_jobs`). Cells run in dependency order, each as a job file run by
`python -m detach.runs.worker` on a local pool, as Ray tasks or as SLURM jobs
(`detach.runs.sweep_launchers`); a lock per sweep file keeps two processes from running one
sweep, and a lock per cell keeps two sweeps from running one cell at the same time (the second
waits for the first). Locks are `flock`s on files under `<runs>/.locks/`: released when a
process dies, and local to one machine unless the runs folder's file system supports them
across machines.
"""

from __future__ import annotations

import contextlib
import fcntl
import hashlib
import os
import time
from collections import deque
from concurrent.futures import FIRST_COMPLETED, Future, wait
from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Sequence

from detach.runs import sweep_launchers
from detach.runs.sweep_config import SweepCfg, load_sweep
from detach.runs.sweep_eta import SweepClock
from detach.runs.sweep_graph import Cell, cell_work, cells, existing_runs, is_complete, runs_alone
from detach.runs.sweep_jobs import cell_steps, job_path
from detach.runs.sweep_launchers import LocalPool, SubmititPool, cell_env, make_pool, run_worker
from detach.runs.job_file import write_job
from detach.config.yaml_source import ConfigError


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


OWNER_POLL_S = 5.0
"""How often a sweep looks again at a cell that another live process is training."""


@dataclass
class CellWork:
    """A callable running one cell under its lock (attributes for the Ray launcher)."""

    cell: Cell
    out: Path
    trials: int
    device: str
    env: dict[str, str]
    cwd: str = field(default_factory=os.getcwd)

    def job(self) -> str | None:
        """The cell's job file, decided and written once no other live process owns its run
        (None: nothing to do). The
        cell lock does not cover every owner (a sweep whose driver was killed leaves its cell
        training; a run started by hand with --cell; Ray and Slurm sweeps take no cell lock):
        starting it again would train it twice, resuming it would be refused as alive."""
        said = False
        while True:
            runs = existing_runs(self.out)  # re-read: another sweep may have run the cell meanwhile
            previous = runs.get(self.cell.key)
            if previous is None or sweep_launchers.STOPPING.is_set() or not previous.owner_alive():
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
        steps = cell_steps(self.cell, runs.get(self.cell.key), parent, self.out, self.trials, self.device, teachers)
        return str(write_job(job_path(self.out, self.cell), self.cell.key, steps)) if steps else None

    def __call__(self) -> tuple[int, str]:
        """Run the cell under its lock: a second sweep that reaches it waits, then finds it done."""
        with file_lock(_lock_path(self.out, self.cell.key), wait_s=None):
            return run_worker(self.job(), self.cwd, self.env)


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
    done_keys = {c.key for c in todo if is_complete(c, runs.get(c.key))}
    pending = deque(c for c in todo if c.key not in done_keys)
    total = len(pending)
    print(f"sweep {label}: {len(todo)} cells, {len(done_keys)} done, {total} to run with {jobs} job(s) "
          f"({launcher}), phase B: {sweep.phase_b}", flush=True)
    if not pending:
        return 0
    pool = make_pool(launcher, jobs, out)
    env, env_alone = cell_env(jobs), cell_env(1)
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
                    alone = runs_alone(cell, running.values(), pending, by_key)
                    work = CellWork(cell, out, sweep.eval_trials, device, env_alone if alone else env)
                    running[pool.submit(work)] = cell
                    clock.start(cell.key)
                    print(f"[{finished}/{total}] {cell.key}: start ({clock.progress()})",
                          flush=True)
            if not running:
                break
            if not isinstance(pool, LocalPool):
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
        sweep_launchers.stop_children()
        if isinstance(pool, SubmititPool):
            pool.cancel()
        raise
    finally:
        pool.close()
    return len(failed)


__all__ = ["CellWork", "file_lock", "run_sweep"]
