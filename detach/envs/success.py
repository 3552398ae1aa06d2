"""Success tests and plan-transition distances (pure functions on [N] tensors).

Each subtask has an anchor (the pelvis, or the carried box for `carry`) and a target; the
subtask is complete once the anchor-to-target distance stays <= `success_threshold` (0.3 m)
for `max_transition_steps` consecutive control steps (60 in training, 20 in evaluation).
Distances (metres):

- traj (follow): XY distance from the pelvis to the trajectory's last waypoint;
- carry: 3-D distance from the box's bbox centre to the destination (`tarpos_K`);
- climb: the target is the object's climb point (top surface, world) raised by
  `climb_pelvis_height` (a standing pelvis); being higher does not count against it:
  sqrt(dxy^2 + max(0, target_z - pelvis_z)^2) ("pelvis at or above the target elevation");
- sit: 3-D distance from the pelvis to the sit point (`tarSitPos`: 0.1 m above the seat).

Per-subtask success scores (the paper's definitions; `subtask_scores`): follow 1 when the
end was reached and the pelvis stayed within the threshold of the path (XY) for at least
`follow_on_path_frac` of the subtask's steps; carry 1 when delivered, 0.5 when the box was
only grasped (lifted >= `GRASP_LIFT` above its resting height), climb and sit 1 when
complete. The LH task succeeds when every subtask scores 1.
"""

from __future__ import annotations

import torch

from detach.config_schema import SKILLS

TRAJ, CARRY, CLIMB, SIT = (SKILLS.index(s) for s in ("traj", "carry", "climb", "sit"))
GRASP_LIFT = 0.1
"""A box counts as grasped once lifted this far (m) above its resting height."""


def climb_distance(root_pos: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    dxy = (root_pos[:, :2] - target[:, :2]).norm(dim=-1)
    below = (target[:, 2] - root_pos[:, 2]).clamp(min=0.0)
    return torch.sqrt(dxy * dxy + below * below)


def subtask_distance(skill: torch.Tensor, root_pos: torch.Tensor, obj_pos: torch.Tensor,
                     target: torch.Tensor) -> torch.Tensor:
    """Anchor-to-target distance [N] for each env's current skill (see module doc).

    skill [N] (index in SKILLS), root_pos [N, 3] pelvis, obj_pos [N, 3] the subtask's
    object (the box for carry), target [N, 3] world (for climb: already raised).
    """
    d_xy = (root_pos[:, :2] - target[:, :2]).norm(dim=-1)
    d_box = (obj_pos - target).norm(dim=-1)
    d_climb = climb_distance(root_pos, target)
    d_sit = (root_pos - target).norm(dim=-1)
    return torch.where(skill == TRAJ, d_xy, torch.where(skill == CARRY, d_box,
                       torch.where(skill == CLIMB, d_climb, d_sit)))


def update_hold(hold: torch.Tensor, dist: torch.Tensor, threshold: float) -> torch.Tensor:
    """Consecutive steps within the threshold, reset to 0 on any step outside it."""
    return torch.where(dist <= threshold, hold + 1, torch.zeros_like(hold))


def subtask_scores(skills: torch.Tensor, done: torch.Tensor, grasped: torch.Tensor,
                   on_path: torch.Tensor, path_steps: torch.Tensor,
                   follow_on_path_frac: float) -> torch.Tensor:
    """Success score [N, S] per subtask (see module doc).

    skills [S]; done, grasped [N, S] bool; on_path, path_steps [N, S] step counts.
    """
    frac = on_path.float() / path_steps.clamp(min=1).float()
    follow = (done & (frac >= follow_on_path_frac)).float()
    carry = torch.where(done, torch.ones_like(frac), 0.5 * grasped.float())
    other = done.float()
    sk = skills[None, :].expand_as(frac)
    return torch.where(sk == TRAJ, follow, torch.where(sk == CARRY, carry, other))


def lh_success(scores: torch.Tensor) -> torch.Tensor:
    """bool [N]: every subtask scored 1."""
    return (scores >= 1.0).all(dim=-1)
