"""Forward kinematics of our humanoid for whole clips, with one MjModel/MjData.

Clips store body positions computed here, so the positions the discriminator sees in
reference motions are exactly those MuJoCo computes for the simulated character from the same
joint angles. `mj_kinematics` costs ~1 microsecond for this model, so a Python loop over
frames is fast enough (offline: clip generation, import, checks).
"""

from __future__ import annotations

from dataclasses import dataclass
from functools import lru_cache

import mujoco
import numpy as np

from detach.character import build_character_model
from detach.character.body import BODY_NAMES, DOF_NAMES

FOOT_BODIES = ("left_foot", "right_foot")
"""Foot order used by `FKResult.foot_*` arrays (index 0 = left)."""
_ROUND = (int(mujoco.mjtGeom.mjGEOM_SPHERE), int(mujoco.mjtGeom.mjGEOM_CAPSULE))
"""Geom types whose lowest surface point is below a point of their axis (`bottom_points`)."""


@dataclass
class FKResult:
    body_pos: np.ndarray
    """[F, 15, 3] body origins, world, metres (BODY_NAMES order)."""
    body_mat: np.ndarray
    """[F, 15, 3, 3] body orientations, world (columns are the body axes)."""
    foot_corners: np.ndarray
    """[F, 2, 8, 3] world corners of the foot boxes (left, right)."""

    @property
    def foot_bottom(self) -> np.ndarray:
        """[F, 2] lowest point (z, metres) of each foot box (left, right)."""
        return self.foot_corners[..., 2].min(axis=-1)


class HumanoidFK:
    """Owns one humanoid MjModel (free root, no floor) and MjData for kinematic queries."""

    def __init__(self) -> None:
        self.model = build_character_model("humanoid", with_floor=False)
        self.data = mujoco.MjData(self.model)
        m = self.model
        self.body_ids = np.array([m.body(n).id for n in BODY_NAMES])
        self.dof_qpos = np.array([m.jnt_qposadr[m.joint(n).id] for n in DOF_NAMES])
        self.foot_geoms = np.array([self._box_of(n) for n in FOOT_BODIES])
        half = m.geom_size[self.foot_geoms]  # [2, 3]
        signs = np.array([[sx, sy, sz] for sx in (-1, 1) for sy in (-1, 1) for sz in (-1, 1)], dtype=np.float64)
        self._corner_local = signs[None] * half[:, None, :]  # [2, 8, 3]

    def _box_of(self, body: str) -> int:
        m = self.model
        bid = m.body(body).id
        ids = [g for g in range(m.ngeom) if m.geom_bodyid[g] == bid and m.geom_type[g] == mujoco.mjtGeom.mjGEOM_BOX]
        return ids[0]

    def set_pose(self, root_pos: np.ndarray, root_quat: np.ndarray, dof_pos: np.ndarray) -> None:
        """Write one pose into `data.qpos` and run mj_kinematics (positions of bodies and geoms)."""
        d = self.data
        d.qpos[0:3] = root_pos
        d.qpos[3:7] = root_quat
        d.qpos[self.dof_qpos] = dof_pos
        mujoco.mj_kinematics(self.model, d)

    def run(self, root_pos: np.ndarray, root_quat: np.ndarray, dof_pos: np.ndarray) -> FKResult:
        """Forward kinematics of F frames: root_pos [F, 3], root_quat [F, 4] wxyz, dof_pos [F, 32]."""
        f = len(dof_pos)
        body_pos = np.empty((f, len(BODY_NAMES), 3))
        body_mat = np.empty((f, len(BODY_NAMES), 3, 3))
        gpos = np.empty((f, 2, 3))
        gmat = np.empty((f, 2, 3, 3))
        d = self.data
        for i in range(f):
            self.set_pose(root_pos[i], root_quat[i], dof_pos[i])
            body_pos[i] = d.xpos[self.body_ids]
            body_mat[i] = d.xmat[self.body_ids].reshape(-1, 3, 3)
            gpos[i] = d.geom_xpos[self.foot_geoms]
            gmat[i] = d.geom_xmat[self.foot_geoms].reshape(-1, 3, 3)
        corners = gpos[:, :, None, :] + np.einsum("fgij,gkj->fgki", gmat, self._corner_local)
        return FKResult(body_pos=body_pos, body_mat=body_mat, foot_corners=corners)

    def bottom_points(self, fk: FKResult, body: str, samples: int = 9) -> np.ndarray:
        """[F, S, 3] the lowest surface points of `body`'s sphere and capsule geoms: below each
        sphere's centre and below `samples` points along each capsule's axis.

        A hand or knee that carries weight rests on what is under one of these points (clips
        declare such bodies: `detach.motion.placement`); the feet use their box corners."""
        b = BODY_NAMES.index(body)
        ends = self._round_geoms(body)
        local = np.concatenate([np.linspace(a, e, samples if np.any(a != e) else 1) for a, e, _ in ends])
        radius = np.concatenate([np.full(samples if np.any(a != e) else 1, r) for a, e, r in ends])
        pts = fk.body_pos[:, b, None, :] + np.einsum("fij,kj->fki", fk.body_mat[:, b], local)
        pts[..., 2] -= radius
        return pts

    def _round_geoms(self, body: str) -> list[tuple[np.ndarray, np.ndarray, float]]:
        """Per sphere/capsule geom of `body`: its axis ends (equal for a sphere) in the body
        frame and its radius."""
        m = self.model
        out = []
        for g in range(m.ngeom):
            if m.geom_bodyid[g] != m.body(body).id or m.geom_type[g] not in _ROUND:
                continue
            axis = np.zeros(3)
            mujoco.mju_rotVecQuat(axis, np.array([0.0, 0.0, 1.0]), m.geom_quat[g])
            half = m.geom_size[g, 1] if m.geom_type[g] == int(mujoco.mjtGeom.mjGEOM_CAPSULE) else 0.0
            out.append((m.geom_pos[g] - half * axis, m.geom_pos[g] + half * axis, float(m.geom_size[g, 0])))
        return out

    def rest_body_pos(self) -> np.ndarray:
        """[15, 3] body origins at the default pose (all hinges 0, root at the origin, upright)."""
        return self.run(np.zeros((1, 3)), np.array([[1.0, 0.0, 0.0, 0.0]]), np.zeros((1, len(DOF_NAMES)))).body_pos[0]


@lru_cache(maxsize=1)
def humanoid_fk() -> HumanoidFK:
    """The process-wide FK helper (not thread-safe: it owns one MjData)."""
    return HumanoidFK()
