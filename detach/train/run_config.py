"""A new run's config: `resolve_run` loads, merges, overrides and validates it
(`detach.config.resolve`) and completes it (`complete_run_config`), once.

`detach.config` checks the structure of a configuration and imports nothing above it; the
names it cannot know (character, physics backend, the plan's skills, reward terms, the model's
network and the skills its config names) are checked here against the registries of their
packages, with the file and line the value came from, and what they decide is filled in
(the character's initial action std, the run's skills, each teacher's checkpoint, the backend's
settings) so that config.yaml records it. The layer of training is the lowest that sees every
registry (`train.checkpoints` and `train.teachers` included); every entry that creates a run
(train, its dry run, a sweep's cell through `detach.runs.actions`) calls `resolve_run`, and the
run is then built from the returned config in memory.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Sequence

from detach.character import character_class
from detach.character.body import NUM_DOF
from detach.config import ConfigError, RunConfig, resolve
from detach.envs.rewards import check_reward_terms
from detach.models.registry import model_class
from detach.motion.labels import MOTION_LABELS
from detach.sim import SimConfigError, check_backend, check_sim, sim_settings
from detach.skills import PlanError, canonical_name, run_skills
from detach.skills.plan import compile_plan
from detach.train.checkpoints import find_init_checkpoint
from detach.train.teachers import ORACLE, teacher_source


def resolve_run(task_path: str | Path, model_name: str = "mlp", overrides: Sequence[str] = (), seed: int = 0,
                device: str = "cpu", presets: Sequence[str] = ()) -> RunConfig:
    """Task YAML + model YAML + presets + overrides -> the validated, completed config of a new
    run (arguments as `detach.config.resolve`); ConfigError naming file, line and key."""
    return complete_run_config(resolve(task_path, model_name, overrides, seed=seed, device=device, presets=presets))


def complete_run_config(cfg: RunConfig) -> RunConfig:
    """`cfg` checked against the registries (ConfigError naming file, line and key), with
    `model.init_noise_std` resolved from the character when it is null and each teacher of
    `train.teachers` pinned to the absolute checkpoint file it names now (a resume from
    another directory, or after the teacher's run trained on, learns from the same teacher)
    and `env.skills` completed (`run_skills`), so that what else the process registered never
    changes the run's observation sizes."""
    origin = cfg.origin
    try:
        character = character_class(cfg.env.character)
    except ValueError as exc:
        raise origin.error(("env", "character"), str(exc)) from None
    if cfg.env.mid_task_init_prob > 0 and not character.can_hold:
        raise origin.error(("env", "mid_task_init_prob"), f"starts episodes holding an object, which character "
                           f"'{cfg.env.character}' cannot (a puppet can); set it to 0 or use env.character=puppet")
    if cfg.env.subtask_start_prob > 0 and not character.scriptable:
        raise origin.error(("env", "subtask_start_prob"), f"starts episodes from states the scripted oracle "
                           f"recorded, and the oracle cannot drive character '{cfg.env.character}' (a puppet "
                           f"can); set it to 0 or use env.character=puppet")
    try:
        check_backend(cfg.sim.backend)
        check_sim(cfg.sim, cfg.device)
    except SimConfigError as exc:
        raise origin.error(("sim", exc.key), str(exc)) from None
    except ValueError as exc:
        raise origin.error(("sim", "backend"), str(exc)) from None
    try:
        plan = compile_plan(cfg.task)
    except PlanError as exc:
        raise origin.error(exc.key, str(exc)) from None
    if cfg.env.subtask_start_prob > 0 and len(plan) < 2:
        raise origin.error(("env", "subtask_start_prob"), f"starts episodes at later subtasks, but task "
                           f"'{cfg.task.name}' has one subtask; set it to 0")
    try:
        skills = run_skills(cfg.env.skills, [sub.skill for sub in plan])
    except ValueError as exc:
        raise origin.error(("env", "skills"), str(exc)) from None
    try:
        check_reward_terms(cfg.rewards)
    except ValueError as exc:
        raise origin.error(("rewards", "terms"), str(exc).removeprefix("rewards.terms: ")) from None
    try:
        model_class(cfg.model)
    except ValueError as exc:
        raise origin.error(("model", "kind"), str(exc)) from None
    invalid_skills = getattr(cfg.model, "invalid_skills", None)  # a model kind's rules on skill names
    problem = invalid_skills(canonical_name) if invalid_skills is not None else None
    if problem is not None:
        raise origin.error(("model", problem[0]), problem[1])
    for i, skill in enumerate(cfg.rewards.paid_skills or ()):
        try:
            canonical_name(skill)
        except ValueError as exc:
            raise origin.error(("rewards", "paid_skills", i), str(exc)) from None
    for skill, weight in cfg.train.amp.skill_weights.items():
        try:
            canonical_name(skill)
        except ValueError as exc:
            raise origin.error(("train", "amp", "skill_weights", skill), str(exc)) from None
        if not weight >= 0:
            raise origin.error(("train", "amp", "skill_weights", skill), f"expected a weight >= 0, found {weight}")
    for label, weight in cfg.train.amp.label_weights.items():
        if label not in MOTION_LABELS:
            raise origin.error(("train", "amp", "label_weights", label),
                               f"expected a motion label ({', '.join(MOTION_LABELS)}), found {label!r}")
        if not weight >= 0:
            raise origin.error(("train", "amp", "label_weights", label), f"expected a weight >= 0, found {weight}")
    pinned: dict[str, str] = {}
    for skill, source in cfg.train.teachers.items():
        try:
            canonical_name(skill)
            pinned[skill] = source if source == ORACLE else str(teacher_source(source)[0].resolve())
        except ValueError as exc:
            raise origin.error(("train", "teachers", skill), str(exc)) from None
        if source == ORACLE and not character.scriptable:
            raise origin.error(("train", "teachers", skill), f"the scripted oracle drives a character with root "
                               f"servos, and '{cfg.env.character}' has none; use env.character=puppet or a trained "
                               "policy's run folder")
    if cfg.train.teacher_only and not cfg.train.teachers:
        raise origin.error(("train", "teacher_only"), "distils the policies of train.teachers, and there are none: "
                           "add +train.teachers.SKILL=RUN or set it to false")
    if cfg.train.clone_start.rounds and cfg.train.init_from:
        raise origin.error(("train", "clone_start", "rounds"), "clones a start for a run from scratch, and "
                           "train.init_from gives it one: set rounds to 0 or drop train.init_from")
    if cfg.train.clone_start.rounds and character.num_actions != NUM_DOF:
        raise origin.error(("train", "clone_start", "rounds"), f"fits the actor to the clips' hinge targets, and "
                           f"character '{cfg.env.character}' acts on more than its {NUM_DOF} hinges; use "
                           "env.character=humanoid")
    base_key = cfg.model.builds_on()
    if base_key and not cfg.train.init_from:
        raise origin.error(("model", base_key), f"model {cfg.model_name} trains on top of an earlier stage's "
                           "policy: set train.init_from to that run folder or checkpoint")
    means = [(("train", "init_action_mean"), cfg.train.init_action_mean)] if cfg.train.init_action_mean else []
    means += [(("train", "init_action_mean_choices", i), choice)
              for i, choice in enumerate(cfg.train.init_action_mean_choices)]
    if cfg.train.init_action_mean and cfg.train.init_action_mean_choices:
        raise origin.error(("train", "init_action_mean_choices"), "chooses the starting action means, and "
                           "train.init_action_mean sets them too: keep one of the two")
    for key, choice in means:
        if not cfg.train.init_from:
            raise origin.error(key[:2], "sets action means of a policy loaded with train.init_from, and this run "
                               "starts from scratch")
        named = character_class(cfg.env.character).named_actions
        for name, value in choice.items():
            if name not in named:
                raise origin.error((*key, name), f"expected an action of the {cfg.env.character} "
                                   f"({', '.join(named) or 'it names none'}), found {name!r}")
            if not -1.0 <= value <= 1.0:
                raise origin.error((*key, name), f"expected a mean in [-1, 1] (actions are clipped there), "
                                   f"found {value:g}")
    if cfg.train.init_action_std is not None and not cfg.train.init_from:
        raise origin.error(("train", "init_action_std"), "sets the action std of a policy loaded with "
                           "train.init_from, and this run starts from scratch (model.init_noise_std sets its std)")
    if cfg.train.init_from:
        try:
            find_init_checkpoint(cfg.train.init_from, report=lambda _line: None)  # said when loaded
        except ConfigError as exc:
            raise origin.error(("train", "init_from"), str(exc).removeprefix("train.init_from: ")) from None
    if pinned != cfg.train.teachers:  # config.yaml records the checkpoint each teacher is, absolute
        cfg = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, teachers=pinned))
    if cfg.sim != sim_settings(cfg.sim):  # config.yaml records what the backend decided
        cfg = dataclasses.replace(cfg, sim=sim_settings(cfg.sim))
    if cfg.model.init_noise_std is None:
        cfg = dataclasses.replace(cfg, model=dataclasses.replace(cfg.model, init_noise_std=character.action_std))
    if cfg.env.skills != skills:  # config.yaml records the run's skills (its observation sizes)
        cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, skills=skills))
    return cfg
