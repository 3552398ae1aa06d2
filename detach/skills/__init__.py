"""detach.skills: every skill of a plan as a plug-in (one module per skill plus a registry).

Built-in skills, in their fixed registry order: `follow` (alias `traj`), `carry`, `climb`,
`sit`. A run's own list of skills (`env.skills`, `run_skills`) orders its `task` one-hot and AMP
condition, so checkpoints stay valid whatever else a process registers.
A new skill is one module that subclasses `Skill` and calls `register_skill`, plus a task YAML
whose plan names it; see docs/ARCHITECTURE.md ("Adding a skill").
"""

from detach.skills.base import RAND, MidTaskStart, PlanError, RewardTerm, Skill, Subtask
from detach.skills.registry import (
    DEFAULT_RUN_SKILLS, canonical_name, display_name, register_skill, run_skills, skill_class, skill_index,
    skill_names, unregister_skill,
)
from detach.skills import follow as _follow  # noqa: E402,F401  (registers, in this order)
from detach.skills import carry as _carry  # noqa: E402,F401
from detach.skills import climb as _climb  # noqa: E402,F401
from detach.skills import sit as _sit  # noqa: E402,F401

__all__ = ["DEFAULT_RUN_SKILLS", "RAND", "MidTaskStart", "PlanError", "RewardTerm", "Skill", "Subtask",
           "canonical_name", "display_name", "register_skill", "run_skills", "skill_class", "skill_index",
           "skill_names", "unregister_skill"]
