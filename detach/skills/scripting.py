"""Helpers of the skills' oracle pieces (the scripted, privileged controller)."""

from __future__ import annotations

import torch

from detach.character.body import DOF_NAMES, NUM_DOF

_DOF = {n: i for i, n in enumerate(DOF_NAMES)}


def hinge_pose(**angles: float) -> torch.Tensor:
    """Hinge targets [32] (rad): the named hinges set, every other hinge 0 (standing)."""
    q = torch.zeros(NUM_DOF)
    for name, v in angles.items():
        q[_DOF[name]] = v
    return q


def hinge_index(name: str) -> int:
    return _DOF[name]
