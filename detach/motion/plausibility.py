"""Kinematic plausibility measures of a clip (used by tests and `detach-motion list --check`).

All distances in metres, speeds in m/s. The support under a foot is the floor (z = 0) or a
prop box listed in the clip's `meta["props"]` (a step, a seat). Self-penetration is measured
with MuJoCo's exact geom distance (`mj_geomDistance`) between non-adjacent bodies. Floating
feet (both feet more than `FLOAT_CLEARANCE` above their support) catch clips lifted off the
floor, e.g. by one glitched frame whose foot dipped below it before import placed the lowest
foot on the floor.

A clip may declare further support bodies, `meta["supports"]` (e.g. a climb's hands and knee
on a box, `detach.motion.placement`). Resting on a prop is what they are there for, so they
are measured like feet rather than as intruders: their own depth into props
(`min_support_prop_distance`) and below their support (`lowest_support`), their slide while
down (`support_skate`), and they count as "on the support" for the gap and floating measures.
Every other body stays in `min_prop_distance`; clips without the key measure as before.
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
    """Maximum over frames of the lower foot's (or declared support body's) height above its
    support (0 = always one foot down)."""
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
    lowest_support: float = np.inf
    """Like lowest_foot for the declared support bodies (the bottom of their spheres/capsules
    above what is under it); >= -0.01 required; inf without `meta["supports"]`."""
    min_support_prop_distance: float = np.inf
    """Smallest distance between a declared support body and a prop (>= -0.01 required: it may
    rest on the prop, not sink into it); inf without supports or props."""
    support_skate: float = 0.0
    """Like foot_skate for the declared support bodies (body origin speed while within 5 mm)."""

    def flags(self) -> list[str]:
        """Short names of what looks wrong: FLOAT (feet off the floor in most frames), BELOW
        (a foot or declared support body more than 1 cm inside its support), RANGE (a hinge
        outside its range), SELF (limbs interpenetrate)."""
        out = []
        if self.floating_fraction >= FLOAT_FLAG:
            out.append("FLOAT")
        if min(self.lowest_foot, self.lowest_support, self.min_support_prop_distance) < -0.01:
            out.append("BELOW")
        if self.range_violation > 1e-3:
            out.append("RANGE")
        if self.min_self_distance <= 0.0:
            out.append("SELF")
        return out


def foot_clearance(clip: MotionClip) -> np.ndarray:
    """[F, 2] lowest point of each foot box (left, right) above the support under it."""
    return _clearances(clip)[0]


def _clearances(clip: MotionClip) -> tuple[np.ndarray, np.ndarray]:
    """([F, 2] feet as `foot_clearance`, [F, K] the lowest point of each declared support body
    (`meta["supports"]`, K of them) above the support under it), from one forward pass."""
    helper = humanoid_fk()
    fk = helper.run(clip.root_pos, clip.root_quat, clip.dof_pos)
    terrain = Terrain.from_meta(clip.meta.get("props"))
    c = fk.foot_corners  # [F, 2, 8, 3]
    feet = (c[..., 2] - terrain.height(c[..., :2])).min(axis=-1)
    pts = [helper.bottom_points(fk, b) for b in _supports(clip)]  # [F, S, 3] each
    sup = [(p[..., 2] - terrain.height(p[..., :2])).min(axis=1) for p in pts]
    return feet, np.stack(sup, axis=1) if sup else np.zeros((clip.num_frames, 0))


def _supports(clip: MotionClip) -> tuple[str, ...]:
    return tuple(clip.meta.get("supports", ()))


def _skate(pos_xy: np.ndarray, clear: np.ndarray, fps: float) -> float:
    """Max horizontal speed [F, K, 2] of points while within 5 mm of their support for 2 frames."""
    speed = np.zeros_like(clear)
    if len(clear) > 1:
        speed[1:] = np.linalg.norm(np.diff(pos_xy, axis=0), axis=-1) * fps
    down = np.zeros_like(clear, dtype=bool)
    down[1:] = (clear[1:] < 0.005) & (clear[:-1] < 0.005)
    return float(speed[down].max()) if down.any() else 0.0


def check_clip(clip: MotionClip, self_pairs=SELF_PAIRS) -> Plausibility:
    """Measure `clip`; see `Plausibility` for what each number means."""
    clear, sup = _clearances(clip)
    contact = np.concatenate([clear, sup], axis=1).min(axis=1)  # [F] lowest foot or support
    rng = dof_ranges()
    viol = np.maximum(rng[:, 0] - clip.dof_pos, clip.dof_pos - rng[:, 1]).max()
    li, ri = BODY_NAMES.index("left_foot"), BODY_NAMES.index("right_foot")
    skate = _skate(clip.body_pos[:, [li, ri], :2], clear, clip.fps)
    sup_pos = clip.body_pos[:, [BODY_NAMES.index(b) for b in _supports(clip)], :2]
    (self_d, self_at), (prop_d, prop_at), sup_prop = _distances(clip, self_pairs)
    disp = np.linalg.norm(clip.root_pos[-1, :2] - clip.root_pos[0, :2])
    travel = root_travel(clip.root_pos, clip.fps)
    return Plausibility(
        lowest_foot=float(clear.min()), max_support_gap=float(contact.max()), foot_skate=skate,
        range_violation=float(max(viol, 0.0)), min_self_distance=self_d, min_prop_distance=prop_d,
        mean_speed=float(disp / clip.duration) if clip.duration > 0 else 0.0,
        worst_self_pair=self_at, worst_prop_body=prop_at,
        floating_fraction=float((contact > FLOAT_CLEARANCE).mean()),
        path_length=travel.path_length, path_speed=travel.path_speed,
        lowest_support=float(sup.min()) if sup.size else np.inf, min_support_prop_distance=sup_prop,
        support_skate=_skate(sup_pos, sup, clip.fps))


@lru_cache(maxsize=8)
def _model_with_props(props_key: tuple) -> tuple[mujoco.MjModel, list[int]]:
    spec = build_character_spec("humanoid", with_floor=False)
    for i, (c, h) in enumerate(props_key):
        g = spec.worldbody.add_geom(name=f"prop{i}")
        g.type = mujoco.mjtGeom.mjGEOM_BOX
        g.pos, g.size = c, h
    m = spec.compile()
    return m, [m.geom(f"prop{i}").id for i in range(len(props_key))]


def _distances(clip: MotionClip, self_pairs) -> tuple[tuple[float, str], tuple[float, str], float]:
    """(min self distance, where), (min prop distance of the other bodies, where), min prop
    distance of the declared support bodies."""
    props = tuple((tuple(p["center"]), tuple(p["half"])) for p in clip.meta.get("props", []))
    m, prop_geoms = _model_with_props(props)
    d = mujoco.MjData(m)
    fk = humanoid_fk()
    body_of = {g: BODY_NAMES[m.geom_bodyid[g] - 1] for g in range(m.ngeom) if m.geom_bodyid[g] > 0}
    geoms = {n: [g for g, b in body_of.items() if b == n] for n in BODY_NAMES}
    pairs = [(g1, g2) for a, b in self_pairs for g1 in geoms[a] for g2 in geoms[b]]
    supports = _supports(clip)
    others = [g for n in BODY_NAMES if n not in ("left_foot", "right_foot") + supports for g in geoms[n]]
    prop_pairs = [(g, p) for g in others for p in prop_geoms]  # feet vs props: foot_clearance
    sup_pairs = [(g, p) for n in supports for g in geoms[n] for p in prop_geoms]
    best_self, best_prop, best_sup = (np.inf, ""), (np.inf, ""), np.inf
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
        for g1, g2 in sup_pairs:
            best_sup = min(best_sup, float(mujoco.mj_geomDistance(m, d, g1, g2, 1.0, None)))
    return best_self, best_prop, best_sup
