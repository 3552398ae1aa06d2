"""A sweep as a graph of cells: which runs it needs, which run each one starts from, and
how far the runs folder already has them.

Every cell (stage x model x seed) is an ordinary run folder whose status.json carries the cell
key `<stage>/<model>/s<seed>/<digest>`; the digest covers everything that defines the run
(task, model, seed, overrides, presets, the parent and teacher cells), so sweeps that share a
stage (the phase-A runs of Tables I-III) share its runs.
"""

from __future__ import annotations

import hashlib
import json
from dataclasses import dataclass
from pathlib import Path
from typing import Collection, Iterable, Mapping, Sequence

from detach.config import resolve
from detach.runfolder.folder import RunFolder, find_runs
from detach.runfolder.names import eval_file
from detach.runs.sweep_config import SweepCfg, load_sweep, task_file
from detach.train.checkpoints import kept_iterations, saves_after
from detach.train.teachers import ORACLE
from detach.config.yaml_source import ConfigError


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


def missing_evals(cell: Cell, run: RunFolder) -> list[Path]:
    """Evaluation tasks of the cell whose eval file the run does not have yet."""
    return [t for t in cell.evals
            if not (run.path / eval_file(None if t.stem == cell.task.stem else t.stem, cell.trial_set)).exists()]


def is_complete(cell: Cell, run: RunFolder | None) -> bool:
    """Finished and evaluated on every task the sweep asks for."""
    if run is None:
        return False
    try:
        state = run.status().state
    except (OSError, ValueError):
        return False
    return state == "finished" and not missing_evals(cell, run)


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


def runs_alone(cell: Cell, running: Collection[Cell], pending: Iterable[Cell], by_key: Mapping[str, Cell]) -> bool:
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
