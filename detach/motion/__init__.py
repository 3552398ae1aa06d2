"""detach.motion: reference motions of the humanoid (clips, packed MotionLib, built-in
synthetic clips, BVH import).

What the env and the trainer use:

    from detach.motion import MotionLib, default_motion_lib
    lib = default_motion_lib(device)                  # or MotionLib([folder, ...], device)
    ids = lib.sample_clips(n, skills=("carry", "walk"))   # clip labels (a skill's motion_labels)
    t = lib.sample_times(ids)
    s = lib.state(ids, t)                             # MotionState, tensors [n, ...]
    w = lib.windows(ids, t, steps=10, dt=1 / 30)      # MotionState, tensors [n, 10, ...]
"""

from detach.motion.builtin import builtin_clips, default_motion_lib
from detach.motion.clip import ClipError, MotionClip, load_clip, load_clips, save_clip
from detach.motion.library import MotionLib
from detach.motion.labels import MOTION_LABELS
from detach.motion.state import MotionState

__all__ = [
    "ClipError", "MOTION_LABELS", "MotionClip", "MotionLib", "MotionState", "builtin_clips",
    "default_motion_lib", "load_clip", "load_clips", "save_clip",
]
