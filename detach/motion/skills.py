"""Skill vocabulary of the motion library and its mapping to task skills.

Every clip carries one skill label from `SKILLS`. The tasks of the paper (traj, carry, climb,
sit) each draw AMP reference windows from a group of labels (`SKILL_GROUPS`), which is what
task-specific discrimination conditions on: a carry policy is judged against carry and walk
clips, not against sitting.
"""

from __future__ import annotations

SKILLS: tuple[str, ...] = ("idle", "walk", "turn", "step_up", "sit", "carry")
"""Clip labels, in a fixed order (a skill's index in this tuple is its id in tensors)."""

SKILL_GROUPS: dict[str, list[str]] = {
    "traj": ["walk", "turn", "idle"],
    "carry": ["carry", "walk"],
    "climb": ["step_up", "walk"],
    "sit": ["sit", "walk"],
}
"""Task skill -> clip labels whose motions the discriminator of that task sees."""


def skill_id(skill: str) -> int:
    """Index of a label in `SKILLS`; ValueError naming the valid labels otherwise."""
    try:
        return SKILLS.index(skill)
    except ValueError:
        raise ValueError(f"unknown skill {skill!r}; expected one of {', '.join(SKILLS)}") from None
