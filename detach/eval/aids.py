"""What a run used that the paper's recipe does not: its aids, named in the tables' rows.

The paper trains every model with PPO, the task rewards and the style (AMP) reward, from
scratch or from the previous stage's policy. Whatever else helps at laptop scale (a teacher, a
start chosen on validation trials, a checkpoint chosen on validation trials, episodes started
from recorded states, extra reward terms) changes what a figure means, so a table row names
it beside the method rather than leaving it to prose. Computed from the run's resolved config
only, so the label of a row is a fact about its cells.
"""

from __future__ import annotations

from typing import Iterable

from detach.config.schema import RewardsCfg, RunConfig
from detach.skills import skill_class, skill_names

ORACLE = "oracle"
PAPER_POWER_COEFF = RewardsCfg().power_coeff
"""The appendix's power penalty per watt (the default): another value is a departure a row names."""


def _added_terms(cfg: RunConfig) -> list[str]:
    """Reward terms the run pays that the skills leave off (default weight 0)."""
    added = []
    for key, weight in sorted(cfg.rewards.terms.items()):
        skill, _, term = key.partition("/")
        if not weight or skill not in skill_names():
            continue
        default = skill_class(skill).reward_terms.get(term)
        if default is not None and default.weight == 0.0:
            added.append(key)
    return added


def run_aids(cfg: RunConfig) -> list[str]:
    """The aids of one run (not of the runs it started from), in a fixed order."""
    t, env, rewards = cfg.train, cfg.env, cfg.rewards
    aids: list[str] = []
    if t.teachers:
        kinds = sorted({"oracle teacher" if src == ORACLE else "teacher" for src in t.teachers.values()})
        aids += kinds
    if env.subtask_start_prob > 0:
        aids.append("oracle-recorded starts")
    if env.mid_task_init_prob > 0:
        aids.append("held-box starts")
    if t.init_action_mean_choices:
        aids.append("chosen start pose")
    elif t.init_action_mean:
        aids.append("set start pose")
    if t.select_checkpoint_trials > 0:
        aids.append("chosen checkpoint")
    if t.critic_warmup_iterations > 0:
        aids.append("critic warm-up")
    if t.init_from and getattr(cfg.model, "tokenizer_from", None):
        aids.append("copied tokenizer")  # TokenHSI's new skill starts from a trained skill's tokenizer
    if t.action_bound_coef > 0 and cfg.model_name not in ("tokenhsi", "tokenhsi_adapt"):
        aids.append("action-bound loss")  # TokenHSI's own loss; an addition to the others
    if t.clone_start.rounds > 0:
        aids.append("cloned start")  # the actor fitted to the clips' hinge targets before PPO
    if t.balance_assist.torque > 0 or t.balance_assist.damping > 0:
        aids.append("balance assist")  # a righting torque on the pelvis while training
    if _added_terms(cfg) or rewards.done_subtask_reward > 0:
        aids.append("added reward terms")
    if t.amp.enabled and t.amp.style_reward_weight == 0:
        aids.append("no style reward")  # not an aid but a departure: a row must say it
    if rewards.power_coeff != PAPER_POWER_COEFF:  # a departure too
        aids.append("no power penalty" if rewards.power_coeff == 0
                    else f"power penalty x{rewards.power_coeff / PAPER_POWER_COEFF:.3g}")
    return aids


def merge_aids(groups: Iterable[Iterable[str]]) -> list[str]:
    """The aids of a policy trained over several runs (a stage and the stages it started
    from), each once, in first-seen order."""
    out: list[str] = []
    for group in groups:
        out += [a for a in group if a not in out]
    return out


def label(method: str, aids: Iterable[str] | None) -> str:
    """A table row's method column: the method, then each aid ("DETACH + chosen checkpoint")."""
    aids = list(aids or [])
    return " + ".join([method, *aids])
