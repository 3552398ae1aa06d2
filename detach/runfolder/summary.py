"""A run's summary (task, model, seed, samples per iteration), from its config.

New run folders carry it in status.json (`RunFolder.create`); for folders of earlier
versions it is read from config.yaml with the CLI's bounded YAML loader
(`detach.runfolder.files.parse_yaml`), leniently: only the keys it needs must be there, so
runs written by an older schema still list.
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from detach.config.schema import RunConfig
from detach.runfolder import files as run_files
from detach.runfolder.messages import RunSummary
from detach.runfolder.names import CONFIG_FILE

SUMMARY_KEYS = ("task_name", "model_name", "seed")
"""The top-level keys of config.yaml a summary needs."""


def samples_per_iteration(num_envs: Any, num_steps_per_env: Any) -> int | None:
    """Environment steps per training iteration (None unless both are integers)."""
    if isinstance(num_envs, int) and isinstance(num_steps_per_env, int):
        return num_envs * num_steps_per_env
    return None


def summary_of_config(cfg: RunConfig) -> RunSummary:
    return RunSummary(cfg.task_name, cfg.model_name, cfg.seed,
                      samples_per_iteration(cfg.sim.num_envs, cfg.train.num_steps_per_env))


def summary_of_config_data(data: Any) -> RunSummary:
    """The summary of a parsed config.yaml (ValueError naming what is missing)."""
    if not isinstance(data, dict):
        raise ValueError("expected a mapping")
    missing = [k for k in SUMMARY_KEYS if k not in data]
    if missing:
        raise ValueError(f"missing keys {', '.join(missing)}")
    sim, train = data.get("sim"), data.get("train")
    return RunSummary(str(data["task_name"]), str(data["model_name"]), data["seed"],
                      samples_per_iteration(sim.get("num_envs") if isinstance(sim, dict) else None,
                                            train.get("num_steps_per_env") if isinstance(train, dict) else None))


def read_config_summary(run_dir: Path) -> RunSummary:
    """config.yaml's summary (OSError if missing, ValueError if refused or malformed)."""
    return summary_of_config_data(run_files.read_yaml(run_dir, CONFIG_FILE))
