"""A run's trained actor, rebuilt for an env: what evaluation, export and play all start from."""

from __future__ import annotations

from pathlib import Path
from typing import Any

import torch

from detach.config_schema import RunConfig
from detach.envs.lh_env import LHEnv
from detach.models.factory import build_actor_critic
from detach.train.checkpoints import check_model, load_module_weights, read_checkpoint
from detach.train.setup import default_action_std


def load_policy(cfg: RunConfig, env: LHEnv, checkpoint: Path, device: str | torch.device = "cpu"
                ) -> tuple[torch.nn.Module, dict[str, Any]]:
    """(actor in eval mode on `device`, the checkpoint's dict) for `env`, after checking that
    the checkpoint holds `cfg`'s model (CheckpointError naming the file otherwise)."""
    state = read_checkpoint(checkpoint, device)
    check_model(state, checkpoint, cfg.model_name, cfg.model.kind)
    actor, _critic = build_actor_critic(cfg.model, env.obs_spec, env.get_observations(),
                                        num_actions=env.num_actions, default_std=default_action_std(cfg))
    load_module_weights(actor, state["actor_state_dict"], checkpoint, "actor")
    return actor.to(device).eval(), state
