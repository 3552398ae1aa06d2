"""Root trajectory from foot contact: plant the supporting foot, derive where the pelvis is.

Procedural clips specify joint angles and the root orientation only; the root position
follows from the rule "the supporting foot does not slide and rests on what is under it".
Each frame the root height is the lowest that keeps every foot on or above its support
(floor or a prop box), so the foot that sets it touches; that foot is planted (its ankle keeps
its world x, y) until the other foot takes over. Result: no foot skating, feet never in the
ground, walking speed emerges from the leg motion (and is tuned through the cycle period).
A clip may name further support bodies (a climb's hands and knee on a box): they take part in
the same rule, so the root follows them while they alone carry the weight.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from detach.motion.kinematics import FKResult, humanoid_fk


@dataclass
class Terrain:
    """Floor at z = 0 plus axis-aligned boxes (steps, seats); metres, world frame."""

    boxes: list[tuple[tuple[float, float, float], tuple[float, float, float]]] = field(default_factory=list)
    """(centre, half sizes) per box."""

    def height(self, xy: np.ndarray) -> np.ndarray:
        """Support height [...] under points xy [..., 2]: the highest box top covering them, else 0."""
        h = np.zeros(np.shape(xy)[:-1])
        for c, half in self.boxes:
            inside = (np.abs(xy[..., 0] - c[0]) <= half[0]) & (np.abs(xy[..., 1] - c[1]) <= half[1])
            h = np.where(inside, np.maximum(h, c[2] + half[2]), h)
        return h

    def to_meta(self) -> list[dict]:
        return [{"center": [float(v) for v in c], "half": [float(v) for v in h]} for c, h in self.boxes]

    @classmethod
    def from_meta(cls, props: list[dict] | None) -> "Terrain":
        return cls([(tuple(p["center"]), tuple(p["half"])) for p in (props or [])])


def ground_root(rel: FKResult, terrain: Terrain, start_xy: tuple[float, float] = (0.0, 0.0),
                switch_margin: float = 1e-3, supports: tuple[str, ...] = ()) -> np.ndarray:
    """Root positions [F, 3] for a pose sequence whose FK was run with the root at the origin.

    `rel` holds body/foot positions relative to the root (FK with root_pos = 0 and the clip's
    root orientations). `switch_margin` (metres) is a hysteresis so that two feet level with
    each other (standing) do not swap the planted foot every frame. `supports` names further
    bodies that can carry the weight like a foot (hands or a knee on a box while climbing):
    the lowest points of their sphere/capsule geoms rest on what is under them and, while one
    of them sets the root height, its body origin is planted as a foot's ankle is.
    """
    f = rel.body_pos.shape[0]
    pts, needs = _contacts(rel, terrain, supports)
    root = np.zeros((f, 3))
    root_xy = np.asarray(start_xy, dtype=np.float64)
    stance, anchor = -1, np.zeros(2)

    for i in range(f):
        if stance >= 0:
            root_xy = anchor - pts[i, stance]
        need = needs(root_xy, i)
        if stance < 0:
            stance = int(np.argmax(need))
            anchor = root_xy + pts[i, stance]
        else:
            best = int(np.argmax(need))
            if need[best] > need[stance] + switch_margin:
                # another contact takes over: it touched down during the last frame, so plant
                # it where it was then and move the root with it from there
                stance = best
                anchor = root[i - 1, :2] + pts[i - 1, stance]
                root_xy = anchor - pts[i, stance]
                need = needs(root_xy, i)
        root[i, :2] = root_xy
        root[i, 2] = need.max()
    return root


def _contacts(rel: FKResult, terrain: Terrain, supports: tuple[str, ...]):
    """Planted points [F, K, 2] (ankles, then support body origins; root-relative) and
    needs(root_xy, i) -> [K]: the root height at which each contact just touches its support."""
    ankle = np.stack((_body(rel, "left_foot"), _body(rel, "right_foot")), axis=1)  # [F, 2, 3]
    corners_xy = rel.foot_corners[..., :2]
    bottom = rel.foot_bottom  # [F, 2]
    low = [humanoid_fk().bottom_points(rel, b) for b in supports]  # [F, S, 3] each
    pts = np.concatenate([ankle[..., :2]] + [_body(rel, b)[:, None, :2] for b in supports], axis=1)

    def needs(xy: np.ndarray, i: int) -> np.ndarray:
        support = terrain.height(corners_xy[i] + xy).max(axis=-1)  # [2] highest under each foot
        feet = support - bottom[i]
        if not supports:
            return feet
        extra = [(terrain.height(p[i, :, :2] + xy) - p[i, :, 2]).max() for p in low]
        return np.concatenate([feet, extra])

    return pts, needs


def _body(rel: FKResult, name: str) -> np.ndarray:
    from detach.character.body import BODY_NAMES

    return rel.body_pos[:, BODY_NAMES.index(name)]


def pose_clip_arrays(root_quat: np.ndarray, dof_pos: np.ndarray, terrain: Terrain,
                     start_xy: tuple[float, float] = (0.0, 0.0),
                     supports: tuple[str, ...] = ()) -> tuple[np.ndarray, np.ndarray]:
    """(root_pos [F, 3], body_pos [F, 15, 3]) for joint angles and root orientations, grounded
    on the feet and the `supports` bodies (`ground_root`)."""
    fk = humanoid_fk()
    rel = fk.run(np.zeros((len(dof_pos), 3)), root_quat, dof_pos)
    root = ground_root(rel, terrain, start_xy, supports=supports)
    return root, rel.body_pos + root[:, None, :]
