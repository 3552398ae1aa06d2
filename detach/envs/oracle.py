"""A scripted, privileged controller that executes any plan, and a random baseline policy.

The oracle proves the task logic (targets, transitions, success tests) end to end: with it the
LH tasks must succeed almost always, while a random policy must almost never succeed. It reads
the env's true state through `env.context()` and asks each skill of the plan for its piece of
the command (`Skill.oracle`: root velocity, heading, pelvis height, hinge pose, grasp), then
the character turns the command into actions (`Character.scripted_actions`). Only a
`scriptable` character (one with root servos) can be driven this way.
"""

from __future__ import annotations

from typing import Callable

import torch

from detach.character import ScriptedCommand, scriptable_characters
from detach.character.body import NUM_DOF, START_HEIGHT
from detach.skills.context import OracleCommand, SkillContext
from detach.torch_math import yaw_of

ORACLE_GROUP = "oracle"
"""Observation group with the oracle's action, where the env provides it (`LHEnv.provide_oracle_actions`)."""


class Oracle:
    """`oracle() -> actions [N, num_actions]`, called once per control step before `env.step`."""

    def __init__(self, env) -> None:
        if not env.character.scriptable:
            raise ValueError(f"the oracle drives a character with root servos: set env.character to one "
                             f"of {', '.join(scriptable_characters())} (found '{env.character.name}')")
        self.env = env
        self.dev = env.device

    def __call__(self, _obs=None, ctx: SkillContext | None = None) -> torch.Tensor:
        """The actions for the env's current state; `ctx` is its context where the caller has
        it already (the env's step), else computed here."""
        env = self.env
        ctx = env.context() if ctx is None else ctx
        n, p = env.num_envs, ctx.state.root_pos
        yaw = yaw_of(ctx.state.root_quat)
        ground = env.services.raster.highest_within(p[:, :2], 0.2, directions=4)  # static surface under the feet
        cmd = OracleCommand(velocity=torch.zeros(n, 2, device=self.dev), yaw_target=yaw.clone(),
                            height=ground + START_HEIGHT, hinges=torch.zeros(n, NUM_DOF, device=self.dev),
                            grasp=torch.full((n,), -1.0, device=self.dev), yaw=yaw, ground=ground)
        for i, skill in env.tracker.skills.items():
            active = ctx.skill == i
            if bool(active.any()):
                skill.oracle(ctx, cmd, active)
        return env.character.scripted_actions(ScriptedCommand(
            velocity=cmd.velocity, yaw=yaw, yaw_target=cmd.yaw_target, height=cmd.height, hinges=cmd.hinges,
            grasp=cmd.grasp))


def random_policy(env, generator: torch.Generator | None = None) -> Callable[[object], torch.Tensor]:
    """Uniform random actions in [-1, 1]."""
    gen = generator or torch.Generator().manual_seed(0)
    return lambda _obs=None: (torch.rand(env.num_envs, env.num_actions, generator=gen) * 2 - 1).to(env.device)
