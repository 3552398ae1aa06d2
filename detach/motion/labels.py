"""Labels of motion clips: what a clip shows (idle, walk, ...).

Every clip carries one label from `MOTION_LABELS` (the clip file's `skill` field). A task
skill (`detach.skills`) names the labels whose clips its AMP style prior draws from
(`Skill.motion_labels`), which is what task-specific discrimination conditions on: a carry
policy is judged against carry and walk clips, not against sitting.
"""

from __future__ import annotations

MOTION_LABELS: tuple[str, ...] = ("idle", "walk", "turn", "step_up", "sit", "carry")
"""Clip labels, in a fixed order (a label's index in this tuple is its id in tensors)."""
