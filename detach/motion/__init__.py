"""detach.motion: reference motions of the humanoid (clips, packed MotionLib, built-in
synthetic clips, BVH import).

What the env and the trainer use:

    from detach.motion import MotionLib, default_motion_lib
    lib = default_motion_lib(device)                  # or MotionLib([folder, ...], device)
    ids = lib.sample_clips(n, skills=("carry", "walk"))   # clip labels (a skill's motion_labels)
    t = lib.sample_times(ids)
    s = lib.state(ids, t)                             # MotionState, tensors [n, ...]
    w = lib.windows(ids, t, steps=10, dt=1 / 30)      # MotionState, tensors [n, 10, ...]

The names below are imported on first use (PEP 562), so that importing a submodule such as
`detach.motion.cli` (`detach-motion --help`) does not pay for torch and MuJoCo.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from detach.lazy_exports import lazy_exports

if TYPE_CHECKING:
    from detach.motion.builtin import builtin_clips, default_motion_lib
    from detach.motion.clip import ClipError, MotionClip, load_clip, load_clips, save_clip
    from detach.motion.labels import MOTION_LABELS
    from detach.motion.library import MotionLib
    from detach.motion.state import MotionState

_HOMES = {
    "builtin_clips": "builtin", "default_motion_lib": "builtin",
    "ClipError": "clip", "MotionClip": "clip", "load_clip": "clip", "load_clips": "clip", "save_clip": "clip",
    "MotionLib": "library", "MOTION_LABELS": "labels", "MotionState": "state",
}

__all__ = sorted(_HOMES)


__getattr__, __dir__ = lazy_exports(__name__, {name: f"{__name__}.{home}" for name, home in _HOMES.items()},
                                    globals())
