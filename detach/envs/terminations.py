"""Episode ends: falls, the skills' own failure conditions, time limits and IET.

`fell`: the pelvis below `env.termination_height`, or with `env.fall_rule: body` any body but
the feet (the heights of the bodies' origins: a hand, knee or head on the floor). Every registered skill may add named
conditions (follow: `traj_failed`, the pelvis more than `env.traj_fail_distance` from its
reference point), evaluated where the env is on that skill; the names are the same for every
plan (false where a skill is absent), so logs and evaluators see stable keys. Terminations
end an episode without bootstrapping; the time limit and IET (`env.iet`: completion of the
last subtask ends the episode; `all` behaves the same, since an earlier subtask's completion
starts the next one; `none` keeps it running) are time-outs (`extras["time_outs"]`).
"""

from __future__ import annotations

import torch

from detach.character.body import BODY_NAMES, FEET
from detach.config.schema import EnvCfg
from detach.skills import Skill, skill_class, skill_names
from detach.skills.context import SkillContext
from detach.torch_math import index_on

_NOT_FEET = tuple(i for i, b in enumerate(BODY_NAMES) if b not in FEET)


class Terminations:
    def __init__(self, cfg: EnvCfg, skills: dict[int, Skill]) -> None:
        self.cfg, self.skills = cfg, skills
        self.names: tuple[str, ...] = ("fell",) + tuple(
            name for s in skill_names() for name in skill_class(s).termination_names)

    def compute(self, ctx: SkillContext) -> dict[str, torch.Tensor]:
        """{name: bool [N]} for every condition in `names`."""
        out = {"fell": self.fell(ctx)}
        for name in self.names[1:]:
            out[name] = torch.zeros_like(out["fell"])
        for i, skill in self.skills.items():
            active = ctx.skill == i
            for name, value in skill.terminations(ctx).items():
                out[name] = out[name] | (active & value)
        return out

    def fell(self, ctx: SkillContext) -> torch.Tensor:
        if self.cfg.fall_rule == "pelvis":
            return ctx.state.root_pos[:, 2] < self.cfg.termination_height
        low = ctx.state.body_pos[:, :, 2] < self.cfg.termination_height
        return low.index_select(1, index_on(_NOT_FEET, low.device)).any(dim=1)

    def outcome(self, ended: dict[str, torch.Tensor], timeout: torch.Tensor, last_done: torch.Tensor
                ) -> tuple[torch.Tensor, torch.Tensor]:
        """(dones, time_outs) [N] bool of the conditions `ended` (`compute`), the time limit
        reached (timeout) and the last subtask completed (last_done); a terminated episode is
        not a time-out."""
        terminated = torch.stack(list(ended.values())).any(dim=0)
        time_outs = (timeout | self.last_subtask_ends(last_done)) & ~terminated
        return terminated | time_outs, time_outs

    def last_subtask_ends(self, last_done: torch.Tensor) -> torch.Tensor:
        """IET: the completion of the last subtask ends the episode (unless `env.iet` is none)."""
        return last_done if self.cfg.iet != "none" else torch.zeros_like(last_done)
