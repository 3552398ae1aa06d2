"""The reward (mjlab style): the skills' named terms, weights from the task YAML.

Every skill declares its terms (`Skill.reward_terms`), named `<skill>/<term>`, each in [0, 1]
with an exp kernel in the style of TokenHSI/AMP HSI tasks; only the current subtask's terms
are paid. Two penalties apply always: `penalty/power` = -power_coeff * sum |torque * joint
velocity| over the 32 hinges (W, scaled by the character's `joint_power_weight`), and
`penalty/dyn_obj_speed` = -coeff * sum over dynamic objects of max(0, speed - threshold)
(m/s) to discourage kicking or throwing boxes; an object the character holds by a constraint
(the puppet's grasp) is exempt, since it moves as the character's own body does: under the
puppet's exploration noise a held box moved at a median 2.5 m/s and the penalty (1.1 per
step) outweighed everything holding it earned, so policies learned to drop it.
`rewards.subtask_bonus` is paid once when a subtask of a paid skill completes
(`bonus/subtask_done`): finishing a subtask ends its high end-of-subtask reward and starts
the next skill's low early reward, which can pay a policy to linger (off by default:
a bonus of 20 lowered LH1's Follow success, docs/PROTOCOL.md).
`rewards.done_subtask_reward` is paid at every step for each completed subtask of a paid skill
(`bonus/subtasks_done`), so that moving on never lowers the per-step reward.
`RewardManager.table()` lists the active terms with their weights at start-up.
`rewards.paid_skills` limits the paid terms to some skills (the zero-shot reading of the
paper's protocol: climb and sit never rewarded).
"""

from __future__ import annotations

from typing import Callable, Sequence

import torch

from detach.config.schema import RewardsCfg
from detach.host_sync import may_any
from detach.skills import canonical_name, run_skills, skill_class, skill_names
from detach.skills.base import Subtask
from detach.skills.context import SkillContext


def registered_terms() -> dict[str, tuple[Callable[[SkillContext], torch.Tensor], float]]:
    """`<skill>/<term>` -> (fn, default weight) of every registered skill, in registry order."""
    return {f"{name}/{term}": (t.fn, t.weight) for name in skill_names()
            for term, t in skill_class(name).reward_terms.items()}


def canonical_term(name: str) -> str:
    """'traj/position' -> 'follow/position' (a skill alias in front); other names unchanged."""
    skill, sep, term = name.partition("/")
    try:
        return f"{canonical_name(skill)}{sep}{term}"
    except ValueError:
        return name


def check_reward_terms(cfg: RewardsCfg) -> dict[str, float]:
    """The weight of every registered term, `rewards.terms` applied; ValueError on a name that
    is no registered term (`detach.train.run_config` reports it with file and line)."""
    terms = registered_terms()
    weights = {canonical_term(k): float(v) for k, v in cfg.terms.items()}
    unknown = sorted(set(weights) - set(terms))
    if unknown:
        raise ValueError(f"rewards.terms: unknown term '{unknown[0]}'; valid terms: {', '.join(terms)}")
    return {name: weights.get(name, w) for name, (_fn, w) in terms.items()}


class RewardManager:
    """Weighted sum of the current skill's terms plus the penalties; per-term logging."""

    def __init__(self, cfg: RewardsCfg, plan: Sequence[Subtask], device: torch.device | str = "cpu",
                 skills: Sequence[str] | None = None) -> None:
        """`skills`: the run's (`run_skills`; by default those of a config without env.skills)."""
        skills = run_skills((), [sub.skill for sub in plan]) if skills is None else tuple(skills)
        self.weights = check_reward_terms(cfg)
        self.cfg = cfg
        self.fns = {name: fn for name, (fn, _w) in registered_terms().items()}
        wanted = None if cfg.paid_skills is None else {canonical_name(s) for s in cfg.paid_skills}
        paid = [s for s in skills if wanted is None or s in wanted]
        self.active = {n: w for n, w in self.weights.items() if w != 0.0 and n.split("/")[0] in paid}
        self.skill_of = {n: skills.index(n.split("/")[0]) for n in self.active}
        self.bonus_skills = [skills.index(s) for s in paid] if cfg.subtask_bonus > 0 else []
        before = [0]
        for sub in plan[:-1]:
            before.append(before[-1] + (sub.skill in paid))
        self.paid_before = torch.tensor(before, dtype=torch.float32, device=device) * cfg.done_subtask_reward
        """[num_subtasks] the per-step pay of an episode on subtask k: its earlier paid subtasks."""

    def table(self) -> str:
        rows = [(n, f"{w:g}") for n, w in self.active.items()]
        rows += [("penalty/power", f"-{self.cfg.power_coeff:g} x W"),
                 ("penalty/dyn_obj_speed",
                  f"-{self.cfg.dyn_obj_speed_penalty_coeff:g} x (v - {self.cfg.dyn_obj_speed_threshold:g})+")]
        if self.bonus_skills:
            rows.append(("bonus/subtask_done", f"{self.cfg.subtask_bonus:g} once"))
        if self.cfg.done_subtask_reward > 0:
            rows.append(("bonus/subtasks_done", f"{self.cfg.done_subtask_reward:g} x done per step"))
        width = max(len(r[0]) for r in rows)
        lines = ["Active reward terms", f"  {'term':<{width}}  weight", f"  {'-' * width}  ------"]
        lines += [f"  {n:<{width}}  {w}" for n, w in rows]
        return "\n".join(lines)

    def compute(self, ctx: SkillContext) -> tuple[torch.Tensor, dict[str, torch.Tensor]]:
        """(reward [N], {term: its value [N], NaN in the envs it does not pay}). A skill's terms
        are left out when no env is on the skill and that is free to know (CPU); on an
        accelerator they are computed, all NaN then, which the training log skips."""
        total = torch.zeros_like(ctx.dist)
        parts: dict[str, torch.Tensor] = {}
        for name, w in self.active.items():
            mask = ctx.skill == self.skill_of[name]
            if not may_any(mask):
                continue
            val = self.fns[name](ctx)
            total = total + torch.where(mask, w * val, torch.zeros_like(val))
            parts[name] = torch.where(mask, val, torch.nan)
        power = -self.cfg.power_coeff * ctx.joint_power
        free = torch.arange(ctx.dyn_speed.shape[-1], device=ctx.dyn_speed.device)[None, :] != ctx.held[:, None]
        excess = (ctx.dyn_speed - self.cfg.dyn_obj_speed_threshold).clamp(min=0.0)
        dyn = -self.cfg.dyn_obj_speed_penalty_coeff * (excess * free).sum(-1)
        parts["penalty/power"], parts["penalty/dyn_obj_speed"] = power, dyn
        return total + power + dyn, parts

    def add_bonuses(self, reward: torch.Tensor, parts: dict[str, torch.Tensor], completed: torch.Tensor,
                    skill: torch.Tensor, subtask: torch.Tensor) -> torch.Tensor:
        """reward [N] plus `completion_bonus` and `done_pay` where they are on, each logged in
        parts; completed, skill as for `completion_bonus`, subtask [N] each env's current one
        after this step's transitions."""
        bonus = self.completion_bonus(completed, skill)
        if bonus is not None:
            reward, parts["bonus/subtask_done"] = reward + bonus, bonus
        done_pay = self.done_pay(subtask)
        if done_pay is not None:
            reward, parts["bonus/subtasks_done"] = reward + done_pay, done_pay
        return reward

    @staticmethod
    def log(parts: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
        """The training log's mean of every term over the envs it paid (NaN: none)."""
        return {f"Episode_Reward/{k}": v.nanmean() for k, v in parts.items()}

    def completion_bonus(self, completed: torch.Tensor, skill: torch.Tensor) -> torch.Tensor | None:
        """[N] `subtask_bonus` where a subtask of a paid skill completed at this step (completed
        [N] bool, skill [N]: the completed subtask's registry index); None with no bonus."""
        if not self.bonus_skills:
            return None
        paid = torch.zeros_like(completed)
        for i in self.bonus_skills:
            paid |= skill == i
        return (completed & paid).float() * self.cfg.subtask_bonus

    def done_pay(self, subtask: torch.Tensor) -> torch.Tensor | None:
        """[N] `done_subtask_reward` x the paid subtasks completed before each env's current
        subtask [N]; None when the term is off."""
        if self.cfg.done_subtask_reward <= 0:
            return None
        return self.paid_before[subtask]
