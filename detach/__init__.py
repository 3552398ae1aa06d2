"""detach: long-horizon human-scene interaction experiments on MuJoCo.

This module is the package's public face: what examples, benchmarks, diagnosis scripts,
notebooks and the dashboard import (`from detach import resolve, make_env, train_run`). Each
name loads its module on first use, so `import detach` (and every `import detach.x`, which runs
this file first) costs neither torch nor MuJoCo, and the layers below keep their one-way
imports. The run folder's own package, `detach.runfolder`, is public as well.

The running functions are those of the command line (`detach-run train` is `train_run`: the
name `train` is the training package).
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from detach.lazy_exports import lazy_exports

__version__ = "0.1.0"

PUBLIC: dict[str, tuple[str, ...]] = {
    # configuration: load, merge, override, validate
    "detach.config": ("ConfigError", "RunConfig", "ModelCfg", "resolve", "dump", "load_task", "find_task_file",
                      "builtin_configs", "load_run_config"),
    "detach.config.keys": ("format_keys", "select"),
    # running: what `detach-run` does, as functions
    "detach.runs.actions": ("RunOutcome", "train_config", "train_run", "resume", "evaluate", "export",
                            "play", "sweep"),
    "detach.cli": ("cli_main",),
    # the run folder and its log
    "detach.runfolder.folder": ("RunFolder", "find_runs"),
    "detach.runfolder.mcap_reader": ("read_metrics", "read_episodes", "iter_messages"),
    "detach.runfolder.log_tail": ("EpisodeKey", "LogTail", "closed_cleanly"),
    "detach.runfolder.messages": ("EpisodeFrame",),
    "detach.runfolder.names": ("STATUS_FILE", "checkpoint_iteration"),
    "detach.runs.mcap_log": ("RunLogWriter",),
    # environments and skills
    "detach.envs.lh_env": ("LHEnv", "make_env"),
    "detach.envs.oracle": ("Oracle",),
    "detach.envs.obs_spec": ("EXAMPLE_SPEC",),
    "detach.envs": ("observations",),
    "detach.sim": ("make_backend",),
    "detach.sim.warp_backend": ("warp_available",),
    "detach.skills": ("Skill", "RewardTerm", "register_skill", "unregister_skill", "skill_class", "skill_names"),
    "detach.skills.context": ("SkillContext", "OracleCommand"),
    "detach.skills.carry": ("HAND_IDS", "box_lifted"),
    "detach.skills.trajectories": ("distance_to_polyline",),
    "detach.torch_math": ("yaw_of", "wrap_angle", "point_box_distance"),
    # characters
    "detach.character": ("Character", "register_character", "make_character", "add_character",
                         "build_character_model", "add_floor", "configure_options"),
    "detach.character.body": ("BODY_NAMES", "DOF_NAMES", "FEET", "FOOT_TO_SOLE"),
    "detach.character.puppet": ("GRASP_ACTION",),
    # motion clips: the built-in library (what the style reward and reference starts read)
    "detach.motion.clip": ("MotionClip",),
    "detach.motion.builtin": ("builtin_clips",),
    # models
    "detach.models": ("StructuredModel", "register_model", "build_actor_critic", "paper_label"),
    "detach.models.configs": ("MLPCfg", "DetachCfg", "TokenHSICfg", "CMLCfg"),
    "detach.models.encoders": ("EnvEncoder",),
    "detach.models.layout": ("HISTORY_GROUPS", "ObsLayout"),
    # training pieces (what `train_run` puts together)
    "detach.train.run_config": ("resolve_run", "complete_run_config"),
    "detach.train.setup": ("seed_everything", "apply_torch_threads", "prepare_assets", "build_runner",
                           "load_initial_weights", "apply_action_means", "merge_normalizers"),
    "detach.train.checkpoints": ("newest_readable_checkpoint",),
    "detach.train.start_library": ("make_training_env",),
    "detach.train.clip_clone": ("clone_clip_start",),
    # evaluation, policies, tables and the pictures of a task
    "detach.eval.episodes": ("run_evaluation",),
    "detach.runs.policy": ("load_policy",),
    "detach.runs.session": ("eval_config",),
    "detach.runs.validation": ("validation_env", "validation_seed", "validation_score"),
    "detach.eval.tables": ("TABLES", "Cell", "Table", "skills_table"),
    "detach.eval.task_markers": ("Disc", "Marker", "PathMemo", "Polyline", "Sphere", "TaskState", "Text",
                                 "task_markers", "task_state"),
    "detach.runs.play": ("VERDICT_HOLD_S", "PolicyRollout"),
}
"""Module -> the public names it defines (or, for `observations`, its submodule)."""

RENAMED: dict[str, str] = {"train_run": "train", "cli_main": "main"}
"""Public name -> the attribute of its module it stands for (where the two differ)."""

_WHERE = {name: module for module, names in PUBLIC.items() for name in names}
__all__ = ["__version__", *_WHERE]


__getattr__, __dir__ = lazy_exports(__name__, _WHERE, globals(), RENAMED)


if TYPE_CHECKING:  # what type checkers and editors see; tests/test_architecture.py keeps it equal to PUBLIC
    from detach.character import (
        Character, add_character, add_floor, build_character_model, configure_options, make_character,
        register_character,
    )
    from detach.character.body import BODY_NAMES, DOF_NAMES, FEET, FOOT_TO_SOLE
    from detach.character.puppet import GRASP_ACTION
    from detach.motion.builtin import builtin_clips
    from detach.motion.clip import MotionClip
    from detach.cli import main as cli_main
    from detach.config import (
        ConfigError, ModelCfg, RunConfig, builtin_configs, dump, find_task_file, load_run_config, load_task,
        resolve,
    )
    from detach.config.keys import format_keys, select
    from detach.envs import observations
    from detach.envs.lh_env import LHEnv, make_env
    from detach.envs.obs_spec import EXAMPLE_SPEC
    from detach.envs.oracle import Oracle
    from detach.eval.episodes import run_evaluation
    from detach.eval.tables import TABLES, Cell, Table, skills_table
    from detach.eval.task_markers import (
        Disc, Marker, PathMemo, Polyline, Sphere, TaskState, Text, task_markers, task_state,
    )
    from detach.models import StructuredModel, build_actor_critic, paper_label, register_model
    from detach.models.configs import CMLCfg, DetachCfg, MLPCfg, TokenHSICfg
    from detach.models.encoders import EnvEncoder
    from detach.models.layout import HISTORY_GROUPS, ObsLayout
    from detach.runfolder.folder import RunFolder, find_runs
    from detach.runfolder.log_tail import EpisodeKey, LogTail, closed_cleanly
    from detach.runfolder.mcap_reader import iter_messages, read_episodes, read_metrics
    from detach.runfolder.messages import EpisodeFrame
    from detach.runfolder.names import STATUS_FILE, checkpoint_iteration
    from detach.runs.actions import (
        RunOutcome, evaluate, export, play, resume, sweep, train_config,
    )
    from detach.runs.actions import train as train_run
    from detach.runs.mcap_log import RunLogWriter
    from detach.runs.play import VERDICT_HOLD_S, PolicyRollout
    from detach.runs.policy import load_policy
    from detach.runs.session import eval_config
    from detach.runs.validation import validation_env, validation_score, validation_seed
    from detach.sim import make_backend
    from detach.sim.warp_backend import warp_available
    from detach.skills import RewardTerm, Skill, register_skill, skill_class, skill_names, unregister_skill
    from detach.skills.carry import HAND_IDS, box_lifted
    from detach.skills.context import OracleCommand, SkillContext
    from detach.skills.trajectories import distance_to_polyline
    from detach.torch_math import point_box_distance, wrap_angle, yaw_of
    from detach.train.checkpoints import newest_readable_checkpoint
    from detach.train.clip_clone import clone_clip_start
    from detach.train.run_config import complete_run_config, resolve_run
    from detach.train.start_library import make_training_env
    from detach.train.setup import (
        apply_action_means, apply_torch_threads, build_runner, load_initial_weights, merge_normalizers,
        prepare_assets, seed_everything,
    )
