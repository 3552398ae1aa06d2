"""A trained run's actor rebuilt for an env, from its config and a checkpoint: what evaluation,
export and play start from (`detach.runs.policy`) and what a teacher is (`detach.train.teachers`)."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from detach.character import character_class
from detach.config.schema import RunConfig
from detach.envs.lh_env import LHEnv
from detach.models.factory import build_actor_critic
from detach.models.structured import training_only_prefixes
from detach.train.checkpoints import check_model, load_module_weights, read_checkpoint


def default_action_std(cfg: RunConfig) -> float:
    """The initial action std of the run's character (`model.init_noise_std: null`)."""
    return character_class(cfg.env.character).action_std


def load_trained_actor(cfg: RunConfig, env: LHEnv, checkpoint: Path, device: str | torch.device = "cpu"
                       ) -> tuple[torch.nn.Module, dict[str, Any]]:
    """(actor in eval mode on `device`, the checkpoint's dict) for `env`, after checking that
    the checkpoint holds `cfg`'s model (CheckpointError naming the file otherwise)."""
    state = read_checkpoint(checkpoint, device, actor_only=True)
    check_model(state, checkpoint, cfg.model_name, cfg.model.kind)
    actor, _critic = build_actor_critic(cfg.model, env.obs_spec, env.get_observations(),
                                        num_actions=env.num_actions, default_std=default_action_std(cfg))
    load_module_weights(actor, state["actor_state_dict"], checkpoint, "actor", may_lack=training_only_prefixes(actor))
    return actor.to(device).eval(), state
