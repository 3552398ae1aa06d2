"""Kinematic plausibility measures of a clip (used by tests and `detach-motion list --check`).

All distances in metres, speeds in m/s. The support under a foot is the floor (z = 0) or a
prop box listed in the clip's `meta["props"]` (a step, a seat). Self-penetration is measured
with MuJoCo's exact geom distance (`mj_geomDistance`) between non-adjacent bodies. Floating
feet (both feet more than `FLOAT_CLEARANCE` above their support) catch clips lifted off the
floor, e.g. by one glitched frame whose foot dipped below it before import placed the lowest
foot on the floor.
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np

from detach.character import build_character_spec
from detach.character.body import BODY_NAMES, dof_ranges
from detach.motion.clip import MotionClip
from detach.motion.kinematics import humanoid_fk
from detach.motion.placement import Terrain
from detach.motion.travel import root_travel

FLOAT_CLEARANCE = 0.03
"""m: a frame whose lower foot is higher than this above its support floats."""
FLOAT_FLAG = 0.5
"""Fraction of floating frames from which `flags()` reports FLOAT (walks and jumps stay below)."""

SELF_PAIRS: tuple[tuple[str, str], ...] = (
    ("left_hand", "torso"), ("right_hand", "torso"), ("left_hand", "pelvis"), ("right_hand", "pelvis"),
    ("left_hand", "left_thigh"), ("right_hand", "right_thigh"), ("left_hand", "right_thigh"),
    ("right_hand", "left_thigh"), ("left_lower_arm", "torso"), ("right_lower_arm", "torso"),
    ("left_lower_arm", "left_thigh"), ("right_lower_arm", "right_thigh"),
    ("left_thigh", "right_thigh"), ("left_shin", "right_shin"), ("left_foot", "right_foot"),
    ("left_hand", "right_hand"),
)
"""Body pairs that must never overlap (none is a parent of the other)."""


@dataclass
class Plausibility:
    """Worst values over the clip."""

    lowest_foot: float
    """Minimum over frames and feet of (foot box bottom - support height); >= -0.01 required."""
    max_support_gap: float
    """Maximum over frames of the lower foot's height above its support (0 = always one foot down)."""
    foot_skate: float
    """Maximum horizontal speed of a foot while it is within 5 mm of its support (two frames)."""
    range_violation: float
    """Largest amount (rad) by which a hinge leaves its range (0 = within dof_ranges())."""
    min_self_distance: float
    """Smallest distance between the geoms of SELF_PAIRS (> 0 = no limb interpenetration)."""
    min_prop_distance: float
    """Smallest distance between any body except the feet and a prop (inf without props)."""
    mean_speed: float
    """Net horizontal root displacement (first to last frame) / duration, m/s."""
    worst_self_pair: str = ""
    """The body pair (and frame) of min_self_distance, e.g. "left_hand/torso@12"."""
    worst_prop_body: str = ""
    """The body (and frame) of min_prop_distance."""
    floating_fraction: float = 0.0
    """Fraction of frames in which both feet are more than FLOAT_CLEARANCE above their support."""
    path_length: float = 0.0
    """Horizontal path of the root, metres (`detach.motion.travel`)."""
    path_speed: float = 0.0
    """path_length / duration, m/s."""

    def flags(self) -> list[str]:
        """Short names of what looks wrong: FLOAT (feet off the floor in most frames), BELOW
        (a foot more than 1 cm inside its support), RANGE (a hinge outside its range),
        SELF (limbs interpenetrate)."""
        out = []
        if self.floating_fraction >= FLOAT_FLAG:
            out.append("FLOAT")
        if self.lowest_foot < -0.01:
            out.append("BELOW")
        if self.range_violation > 1e-3:
            out.append("RANGE")
        if self.min_self_distance <= 0.0:
            out.append("SELF")
        return out


def foot_clearance(clip: MotionClip) -> np.ndarray:
    """[F, 2] lowest point of each foot box (left, right) above the support under it."""
    fk = humanoid_fk().run(clip.root_pos, clip.root_quat, clip.dof_pos)
    c = fk.foot_corners  # [F, 2, 8, 3]
    terrain = Terrain.from_meta(clip.meta.get("props"))
    return (c[..., 2] - terrain.height(c[..., :2])).min(axis=-1)


def check_clip(clip: MotionClip, self_pairs=SELF_PAIRS) -> Plausibility:
    """Measure `clip`; see `Plausibility` for what each number means."""
    clear = foot_clearance(clip)
    rng = dof_ranges()
    viol = np.maximum(rng[:, 0] - clip.dof_pos, clip.dof_pos - rng[:, 1]).max()
    li, ri = BODY_NAMES.index("left_foot"), BODY_NAMES.index("right_foot")
    feet = clip.body_pos[:, [li, ri], :2]
    speed = np.zeros_like(clear)
    if clip.num_frames > 1:
        v = np.linalg.norm(np.diff(feet, axis=0), axis=-1) * clip.fps
        speed[1:] = v
    down = np.zeros_like(clear, dtype=bool)
    down[1:] = (clear[1:] < 0.005) & (clear[:-1] < 0.005)
    skate = float(speed[down].max()) if down.any() else 0.0
    (self_d, self_at), (prop_d, prop_at) = _distances(clip, self_pairs)
    disp = np.linalg.norm(clip.root_pos[-1, :2] - clip.root_pos[0, :2])
    travel = root_travel(clip.root_pos, clip.fps)
    return Plausibility(
        lowest_foot=float(clear.min()), max_support_gap=float(clear.min(axis=1).max()), foot_skate=skate,
        range_violation=float(max(viol, 0.0)), min_self_distance=self_d, min_prop_distance=prop_d,
        mean_speed=float(disp / clip.duration) if clip.duration > 0 else 0.0,
        worst_self_pair=self_at, worst_prop_body=prop_at,
        floating_fraction=float((clear.min(axis=1) > FLOAT_CLEARANCE).mean()),
        path_length=travel.path_length, path_speed=travel.path_speed)


@lru_cache(maxsize=8)
def _model_with_props(props_key: tuple) -> tuple[mujoco.MjModel, list[int]]:
    spec = build_character_spec("humanoid", with_floor=False)
    for i, (c, h) in enumerate(props_key):
        g = spec.worldbody.add_geom(name=f"prop{i}")
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.pos, g.size = c, h
    m = spec.compile()
    return m, [m.geom(f"prop{i}").id for i in range(len(props_key))]


def _distances(clip: MotionClip, self_pairs) -> tuple[tuple[float, str], tuple[float, str]]:
    props = tuple((tuple(p["center"]), tuple(p["half"])) for p in clip.meta.get("props", []))
    m, prop_geoms = _model_with_props(props)
    d = mujoco.MjData(m)
    fk = humanoid_fk()
    body_of = {g: BODY_NAMES[m.geom_bodyid[g] - 1] for g in range(m.ngeom) if m.geom_bodyid[g] > 0}
    geoms = {n: [g for g, b in body_of.items() if b == n] for n in BODY_NAMES}
    pairs = [(g1, g2) for a, b in self_pairs for g1 in geoms[a] for g2 in geoms[b]]
    no_feet = [g for n in BODY_NAMES if n not in ("left_foot", "right_foot") for g in geoms[n]]
    prop_pairs = [(g, p) for g in no_feet for p in prop_geoms]  # feet vs props: foot_clearance
    best_self, best_prop = (np.inf, ""), (np.inf, "")
    for i in range(clip.num_frames):
        d.qpos[:3], d.qpos[3:7] = clip.root_pos[i], clip.root_quat[i]
        d.qpos[fk.dof_qpos] = clip.dof_pos[i]
        mujoco.mj_kinematics(m, d)
        for g1, g2 in pairs:
            dist = mujoco.mj_geomDistance(m, d, g1, g2, 1.0, None)
            if dist < best_self[0]:
                best_self = (float(dist), f"{body_of[g1]}/{body_of[g2]}@{i}")
        for g1, g2 in prop_pairs:
            dist = mujoco.mj_geomDistance(m, d, g1, g2, 1.0, None)
            if dist < best_prop[0]:
                best_prop = (float(dist), f"{body_of[g1]}@{i}")
    return best_self, best_prop
