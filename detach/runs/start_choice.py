"""`train.init_action_mean_choices`: start a stage from the best of several action means.

A later stage of the progressive protocol starts from an earlier stage's policy and may set
some action means (`train.init_action_mean`: the puppet's grasp, the arms' hinges). Which
arm pose lets a Follow policy reach a box depends on where that policy holds its arms: the
oracle's reach pose doubled one Follow cell's Carry score before training and halved
another's. So the run scores each choice on validation trials of its own task and keeps the
best, the same rule for every model.
"""

from __future__ import annotations

import torch

from detach.config.schema import RunConfig
from detach.runs.validation import validation_env, validation_score
from detach.train.setup import action_mean_layer, apply_action_means


def choose_action_means(actor: torch.nn.Module, cfg: RunConfig, device: str) -> str:
    """Score `actor` (mean actions, weights unchanged) with each of the run's
    `init_action_mean_choices` on `init_choice_trials` validation trials, then leave it with
    the best one (highest LH mean; the first on a tie). Returns the log line."""
    choices, trials = cfg.train.init_action_mean_choices, cfg.train.init_choice_trials
    layer = action_mean_layer(actor)
    loaded = {k: v.clone() for k, v in layer.state_dict().items()}
    env = validation_env(cfg, trials, device)
    scores = []
    for choice in choices:
        layer.load_state_dict(loaded)
        apply_action_means(actor, cfg.env.character, choice)
        scores.append(validation_score(env, lambda obs: actor(obs), cfg, trials))
    best = max(range(len(choices)), key=lambda i: (scores[i], -i))
    layer.load_state_dict(loaded)
    applied = apply_action_means(actor, cfg.env.character, choices[best])
    listed = "; ".join(f"{_describe(c)}: {s:.2f}" for c, s in zip(choices, scores))
    return (f"train.init_action_mean_choices: LH mean over {trials} validation trials each: {listed}; "
            f"starting from choice {best} ({applied})")


def _describe(means: dict[str, float]) -> str:
    return "{" + ", ".join(f"{k}: {v:g}" for k, v in means.items()) + "}"
