"""The configuration of a run, in one pipeline that imports nothing above it (no torch).

load (`yaml_source`: YAML with file and line of every value) -> merge (`loader`: `extends:`,
task + model + presets) -> override (`a.b=value`) -> build and validate (`validate.Builder`
walks the dataclasses of `schema`, whose type hints are the schema; `ranges`: the range each
numeric field declares) -> a frozen `RunConfig`. `dump` writes it as a self-contained YAML that
`load_run_config` reads back identically; `keys` lists every key (`detach-run keys`). The names
only higher layers know (character, skills, reward terms, networks) are checked, and what they
decide filled in, once, by `detach.train.run_config.resolve_run`.
"""

from detach.config.loader import (
    apply_overrides, builtin_configs, dump, find_config_file, find_model_file, find_task_file, load_merged,
    load_run_config, load_task, resolve, task_name_of, to_dict,
)
from detach.config.schema import (
    AmpCfg, EnvCfg, EvalCfg, HeightMapCfg, HumanoidCfg, KeepCheckpointsCfg, ModelCfg, RewardsCfg, RunConfig,
    SceneObjectCfg, SimCfg, StagesCfg, TaskCfg, TrainCfg, TrajectoryGenCfg,
)
from detach.config.yaml_source import ConfigError, ConfigOrigin

__all__ = [
    "AmpCfg", "ConfigError", "ConfigOrigin", "EnvCfg", "EvalCfg", "HeightMapCfg", "HumanoidCfg",
    "KeepCheckpointsCfg", "ModelCfg", "RewardsCfg", "RunConfig", "SceneObjectCfg", "SimCfg", "StagesCfg",
    "TaskCfg", "TrainCfg", "TrajectoryGenCfg", "apply_overrides", "builtin_configs", "dump", "find_config_file",
    "find_model_file", "find_task_file", "load_merged", "load_run_config", "load_task", "resolve",
    "task_name_of", "to_dict",
]
