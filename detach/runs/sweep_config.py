"""A sweep file as typed settings: its models, seeds, stages, evaluations and presets.

A sweep YAML (configs/sweeps/; `extends:` works as for tasks) names models, seeds and a list
of stages. A stage is a task trained for every model and seed, optionally starting from the
run of an earlier stage (`init_from: <stage>`: same model and seed; `train.init_from`), with
overrides; `eval` says on which tasks each stage's runs are evaluated. The two readings of the
paper's phase B (`phase_b: zero_shot | composition`, docs/PROTOCOL.md) select per-stage
overrides and model substitutions (`zero_shot:` / `composition:` in a stage). A preset
(`--preset NAME`, `--quick` = `--preset quick`) replaces seeds and trials, adds overrides, and
may give a stage's cells teachers (`stage_teachers`: per skill, the run of an earlier stage on
its `init_from` chain, or the scripted oracle; `train.teachers`) and add stages that continue
a stage (they take over its evaluations). `load_sweep` checks all of it, as one-line errors
naming the file and key; `detach.runs.sweep_graph` turns it into cells.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Literal, Sequence

from detach.config import find_config_file, load_merged
from detach.config.validate import Builder
from detach.eval.trial_sets import TrialSetError, check_test_offset
from detach.skills import canonical_name
from detach.train.teachers import ORACLE
from detach.config.yaml_source import ConfigError

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
