"""Retargeting that checks itself: how far the humanoid's bones point from the source's.

Why: a real sitting BVH imported with 7.4% of its angles clipped and a flailing leg, and the
only hint was the clipping share and a floating-clip warning. Every import now compares, frame
by frame, the direction of each of our mapped bones with the source bone it should follow
(after the map's rest-pose alignment), and reports the worst joints.

Per mapped joint of ours (its body b, our rest bone v_b in b's frame):
- with an `aim`, the target is the source's own bone src -> aim, from the source skeleton's
  forward kinematics (its rest offsets and per-frame rotations, in our axes): independent of
  how the angles were solved, so wrong axes, Euler branches, clipping or a lost knee twist all
  show;
- without one (abdomen, neck, ankles), the target is v_b turned by the source joint's world
  rotation (with the map's rest alignment); our foot's bone is its forward axis (heel to toe),
  torso and head point up.
The measured direction is R_b v_b from MuJoCo FK of the clip's angles. Targets of the import
(docs/MOCAP.md): at most 1% of angles clipped, a foot at ankle height (within 3 cm of the
floor) in at least 90% of the frames of standing or seated clips, and a mean bone-direction
error under 10 degrees.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from detach.character.body import BODY_NAMES, JOINT_GROUPS
from detach.motion.rotations import quat_mul, quat_rotate

CLIPPED_TARGET = 0.01
"""Largest share of all angles clipped to joint ranges."""
GROUNDED_TARGET = 0.9
"""Smallest share of frames with a foot at ankle height, for standing and seated clips."""
BONE_ERROR_TARGET_DEG = 10.0
"""Largest mean bone-direction error, degrees."""
GROUNDED_SKILLS = ("idle", "sit")
"""Clip labels (`--skill`) of standing and seated clips: `grounded` is a target for them."""


@dataclass(frozen=True)
class JointCheck:
    """One of our joints: how well its bone follows the source."""

    name: str
    bone_error_deg: float
    """Mean over frames of the angle between our bone and the source's, degrees."""
    max_error_deg: float
    clipped_frames: float
    """Share of frames in which any hinge of this joint was clipped to its range."""


@dataclass(frozen=True)
class RetargetCheck:
    """The check of one import (stored in the clip's meta["check"])."""

    joints: tuple[JointCheck, ...]
    bone_error_deg: float
    """Mean over mapped joints and frames, degrees."""
    clipped_fraction: float
    """Share of all (frame, hinge) angles clipped."""
    grounded_fraction: float
    """Share of frames in which the lower foot is within 3 cm of the floor."""

    def worst(self, count: int = 3) -> list[JointCheck]:
        """Joints with the largest bone error (then most clipped frames), worst first."""
        ranked = sorted(self.joints, key=lambda j: (-j.bone_error_deg, -j.clipped_frames))
        return ranked[:count]

    def problems(self, skill: str) -> list[str]:
        """The targets this import misses (empty: all met)."""
        out = []
        if self.clipped_fraction > CLIPPED_TARGET:
            out.append(f"{100 * self.clipped_fraction:.1f}% clipped > {100 * CLIPPED_TARGET:.0f}%")
        if skill in GROUNDED_SKILLS and self.grounded_fraction < GROUNDED_TARGET:
            out.append(f"feet down in {100 * self.grounded_fraction:.0f}% < {100 * GROUNDED_TARGET:.0f}% of frames")
        if self.bone_error_deg >= BONE_ERROR_TARGET_DEG:
            out.append(f"bone error {self.bone_error_deg:.1f} >= {BONE_ERROR_TARGET_DEG:.0f} deg")
        return out

    def summary(self, count: int = 3) -> str:
        """One phrase for the import line: mean error and the worst joints."""
        worst = ", ".join(f"{j.name} {j.bone_error_deg:.1f} deg, {j.clipped_frames:.0%} of frames clipped"
                          for j in self.worst(count))
        return f"bones off by {self.bone_error_deg:.1f} deg on average (worst: {worst})"

    def as_meta(self) -> dict:
        """JSON-ready form for the clip's meta."""
        return {"bone_error_deg": round(self.bone_error_deg, 3), "clipped_fraction": round(self.clipped_fraction, 5),
                "grounded_fraction": round(self.grounded_fraction, 4),
                "joints": {j.name: {"bone_error_deg": round(j.bone_error_deg, 3),
                                    "max_error_deg": round(j.max_error_deg, 3),
                                    "clipped_frames": round(j.clipped_frames, 4)} for j in self.joints}}

    @classmethod
    def from_meta(cls, meta: dict) -> RetargetCheck | None:
        """The check stored by an import, or None (built-in clips, older imports)."""
        raw = meta.get("check") if isinstance(meta, dict) else None
        if not isinstance(raw, dict):
            return None
        try:
            joints = tuple(JointCheck(n, float(v["bone_error_deg"]), float(v["max_error_deg"]),
                                      float(v["clipped_frames"])) for n, v in raw["joints"].items())
            return cls(joints, float(raw["bone_error_deg"]), float(raw["clipped_fraction"]),
                       float(raw["grounded_fraction"]))
        except (KeyError, TypeError, ValueError, AttributeError):
            return None


def angle_deg(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """[...] angles in degrees between vectors a and b [..., 3] (any length)."""
    na = a / np.maximum(np.linalg.norm(a, axis=-1, keepdims=True), 1e-12)
    nb = b / np.maximum(np.linalg.norm(b, axis=-1, keepdims=True), 1e-12)
    return np.degrees(np.arccos(np.clip((na * nb).sum(axis=-1), -1.0, 1.0)))


def make_check(errors: dict[str, np.ndarray], clipped_frames: dict[str, float], clipped_fraction: float,
               grounded_fraction: float) -> RetargetCheck:
    """A RetargetCheck from per-joint errors [F] (degrees) and per-joint clipped-frame shares."""
    joints = tuple(JointCheck(n, float(e.mean()) if e.size else 0.0, float(e.max()) if e.size else 0.0,
                              float(clipped_frames.get(n, 0.0))) for n, e in errors.items())
    mean = float(np.mean([j.bone_error_deg for j in joints])) if joints else 0.0
    return RetargetCheck(joints, mean, float(clipped_fraction), float(grounded_fraction))


def bone_vector(body: str) -> np.ndarray:
    """Our rest bone of `body` in its own frame (unit): to its only child body; the foot's is
    its forward axis (heel to toe), a body without children points up."""
    from detach.motion.joint_map import child_bodies
    from detach.motion.kinematics import humanoid_fk

    if body.endswith("_foot"):
        return np.array([1.0, 0.0, 0.0])
    kids = child_bodies(body)
    if len(kids) != 1:
        return np.array([0.0, 0.0, 1.0])
    rest = humanoid_fk().rest_body_pos()
    v = rest[BODY_NAMES.index(kids[0])] - rest[BODY_NAMES.index(body)]
    return v / np.linalg.norm(v)


def bone_axis(body: str) -> int:
    """The body axis (0, 1, 2) nearest to its bone: the one to match first."""
    return int(np.argmax(np.abs(bone_vector(body))))


def source_positions(bvh, c: np.ndarray, g: np.ndarray) -> np.ndarray:
    """[F, J, 3] source joint positions relative to the file's root, in our axes (source
    units): its own forward kinematics from rest offsets and world rotations g (our axes)."""
    f = bvh.num_frames
    pos = np.zeros((f, len(bvh.names), 3))
    for j, p in enumerate(bvh.parents):
        if p >= 0:
            offset = bvh.joint_pos.get(j, np.broadcast_to(bvh.offsets[j], (f, 3))) @ c.T
            pos[:, j] = pos[:, p] + quat_rotate(g[:, p], offset)
    return pos


def bone_errors(bvh, bound, c: np.ndarray, g: np.ndarray, rest_fix: dict[str, np.ndarray],
                body_mat: np.ndarray) -> dict[str, np.ndarray]:
    """{our mapped joint: [F] degrees between our bone and the source's} (module docstring).
    g: [F, J, 4] source world rotations in our axes; rest_fix: the map's rest alignment Q per
    joint; body_mat: [F, 15, 3, 3] our bodies' world rotations (MuJoCo FK of the angles)."""
    pos = source_positions(bvh, c, g)
    out: dict[str, np.ndarray] = {}
    for grp in JOINT_GROUPS:
        if grp.name not in bound.joints:
            continue
        src, aim = bound.joints[grp.name]
        v = bone_vector(grp.body)
        ours = body_mat[:, BODY_NAMES.index(grp.body)] @ v
        if aim:
            theirs = pos[:, bvh.index(aim)] - pos[:, bvh.index(src)]
        else:
            q = quat_mul(g[:, bvh.index(src)], np.broadcast_to(rest_fix[grp.name], (len(g), 4)))
            theirs = quat_rotate(q, np.broadcast_to(v, (len(g), 3)))
        out[grp.name] = angle_deg(ours, theirs)
    return out
