"""Teacher policies per skill (`train.teachers`): kickstarting one network from skill experts.

Kickstarting (Schmitt et al. 2018, "Kickstarting Deep Reinforcement Learning"): while PPO
trains the student on the task reward, an auxiliary loss pulls the student's mean action
toward a frozen teacher's on the steps of the teacher's skill,

    L = train.teacher_weight * (1/B) * sum_b sum_k [skill(b) = k] * mean_a (mu(o_b) - clip(mu_k(o_b)))^2,

over the same rollout PPO learns from (the student's own states, so the teacher corrects
where the student goes, as DAgger does); the teacher's mean is clipped to [-1, 1] as the env
clips actions (beyond, every value acts the same). Why here: one network taught a new skill by PPO
alone loses the skills it had (results/laptop/NOTEBOOK.md: Climb learned at its own step took
Follow from 1.00 to 0.00), while a policy trained on one skill in place does that skill; a
teacher per skill keeps each skill's behaviour as the target while the rewards of every
skill are paid. A skill's teacher may be the very policy the student starts from (a frozen
copy of `train.init_from`), which makes the term a preservation term for the skills that
policy already has.

The skill of a step is the `task` observation group (the skill one-hot, registry order); a
teacher is any run folder (its policy) or checkpoint file of a run whose model
builds for this env (it keeps its own observation normalisers), or `oracle`: the scripted
oracle (`detach.envs.oracle`), whose action in the true state the env stores with every
observation (`LHEnv.provide_oracle_actions`; a scriptable character only). Taught so, on the
student's own states, the term is DAgger with a privileged expert: the way to teach a skill
the oracle does and no trained policy does yet (the puppet sitting on LH1's raised chair).
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch
from tensordict import TensorDict

from detach.config import load_run_config
from detach.config.schema import RunConfig
from detach.envs.lh_env import LHEnv
from detach.envs.oracle import ORACLE_GROUP
from detach.runfolder.folder import RunFolder
from detach.runfolder.names import CONFIG_FILE
from detach.skills import canonical_name
from detach.train.checkpoints import find_init_checkpoint
from detach.train.trained_actor import load_trained_actor
from detach.config.yaml_source import ConfigError

ORACLE = "oracle"
"""The `train.teachers` value that names the scripted oracle instead of a run."""


class OracleTeacher(torch.nn.Module):
    """The scripted oracle as a teacher: its action is the observation group the env adds."""

    def forward(self, obs: TensorDict) -> torch.Tensor:
        return obs[ORACLE_GROUP]


def teacher_source(source: str) -> tuple[Path, Path]:
    """(checkpoint file, run folder) of a teacher: a run folder (its policy, as for
    `train.init_from`) or a checkpoint file inside one (ValueError: the teacher's model
    config lives in its run folder's config.yaml)."""
    try:
        checkpoint, run = find_init_checkpoint(source)
    except ConfigError as exc:  # worded for train.init_from
        raise ValueError(str(exc).removeprefix("train.init_from: ")) from None
    if run is None or not RunFolder(run).config_path.is_file():
        raise ValueError(f"{source}: a teacher needs its run folder's {CONFIG_FILE} (the model it was trained "
                         "with); give the run folder or a checkpoint inside its checkpoints/")
    return checkpoint, run


@dataclass
class Teachers:
    """Frozen teacher actors, each with the skills it teaches (names and one-hot columns): a
    policy that teaches several skills (the preservation case: Follow and Carry from the run
    the student starts from) is loaded and run once."""

    actors: list[torch.nn.Module]
    skills: list[list[str]]
    columns: list[list[int]]
    weight: float

    def loss(self, mu: torch.Tensor, obs: TensorDict) -> tuple[torch.Tensor, dict[str, float]]:
        """(weighted kickstarting loss, per-skill mean squared action difference and share of
        the batch) of the student's mean actions mu [B, A] over a batch of rollout observations."""
        onehot = obs["task"]
        total = torch.zeros((), device=mu.device)
        logs: dict[str, float] = {}
        for teacher, skills, columns in zip(self.actors, self.skills, self.columns):
            with torch.no_grad():  # the env clips actions: a teacher's mean beyond acts as at the clip
                target = teacher(obs).clamp(-1.0, 1.0)
            sq = (mu - target).square().mean(-1)
            for skill, column in zip(skills, columns):
                mask = onehot[:, column]
                total = total + (sq * mask).sum()
                count = mask.sum()
                logs[f"teacher/{skill}/mse"] = float((sq.detach() * mask).sum() / count.clamp(min=1.0))
                logs[f"teacher/{skill}/share"] = float(count / mask.numel())
        total = self.weight * total / max(onehot.shape[0], 1)
        logs["teacher/loss"] = float(total.detach())
        return total, logs


def load_teachers(cfg: RunConfig, env: LHEnv, device: str | torch.device) -> Teachers | None:
    """The teachers of `cfg.train.teachers` built for `env`, one per distinct checkpoint (None
    when there are none). An `oracle` teacher makes `env` provide the oracle's actions, so
    call this before a runner takes the env's first observations."""
    if not cfg.train.teachers:
        return None
    names = env.skills
    by_checkpoint: dict[Path | str, int] = {}
    teachers = Teachers([], [], [], cfg.train.teacher_weight)
    for skill, source in cfg.train.teachers.items():
        found = None if source == ORACLE else teacher_source(source)
        key = ORACLE if found is None else found[0].resolve()
        if key not in by_checkpoint:
            by_checkpoint[key] = len(teachers.actors)
            teachers.actors.append(_build_teacher(found, env, device))
            teachers.skills.append([])
            teachers.columns.append([])
        name = canonical_name(skill)
        teachers.skills[by_checkpoint[key]].append(name)
        teachers.columns[by_checkpoint[key]].append(names.index(name))
    return teachers


def _build_teacher(found: tuple[Path, Path] | None, env: LHEnv, device: str | torch.device) -> torch.nn.Module:
    """The frozen actor of a teacher's (checkpoint, run folder), or the oracle's for None."""
    if found is None:
        env.provide_oracle_actions()
        return OracleTeacher()
    checkpoint, run = found
    actor, _state = load_trained_actor(load_run_config(RunFolder(run).config_path), env, checkpoint, device)
    return actor.requires_grad_(False)
