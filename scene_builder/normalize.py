"""Mesh standardisation: any input frame -> metres, Z up, facing +Y, bbox centre at the origin.

Input conventions (the paper's appendix, "mesh standardisation"):
- `up="y"`: 3D-FUTURE's `normalized_model.obj` convention: Y up, the object's front towards +Z.
  A +90 deg rotation about X brings Y up to Z up, but turns that front to -Y, so a 180 deg yaw
  follows; together they are the fixed matrix `Y_UP_TO_Z_UP` below: (x, y, z) -> (-x, z, y).
- `up="z"`: already Z up and facing +Y; only the optional user yaw, scale and recentring apply.
Then optionally `flip` (180 deg about Y: turns an upside-down model over, its front stays +Y),
an extra yaw (degrees, about +Z), then scale (uniform `scale`, or per-axis to an exact bbox
`size` in metres), then recentring on the bounding-box centre.
"""

from __future__ import annotations

from collections.abc import Sequence
from dataclasses import dataclass

import numpy as np
import trimesh

Y_UP_TO_Z_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
"""Rotation (det +1) = R_z(180 deg) @ R_x(+90 deg): Y-up/front +Z -> Z-up/front +Y."""
FLIP = np.diag([-1.0, 1.0, -1.0])
"""Upside down about the front-back axis: 180 deg about Y (x -> -x, z -> -z; front stays +Y)."""
UP_AXES = ("y", "z")


def up_rotation(up: str, flip: bool = False) -> np.ndarray:
    """Rotation from a source frame with `up` ('y' 3D-FUTURE, 'z') to Z up, facing +Y."""
    if up not in UP_AXES:
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    rot = Y_UP_TO_Z_UP if up == "y" else np.eye(3)
    return FLIP @ rot if flip else rot


def yaw_matrix(degrees: float) -> np.ndarray:
    """Rotation about +Z by `degrees` (counter-clockwise seen from above); exact for k*90."""
    quarter, rest = divmod(float(degrees), 90.0)
    if rest == 0.0:  # exact integers so a 90 deg yaw does not blur the bbox by 1e-17
        c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][int(quarter) % 4]
    else:
        c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=float)


@dataclass(frozen=True)
class FrameTransform:
    """source vertices v -> asset frame: ((v @ rotation.T) * factors) - centre, in that order
    (the order of the arithmetic is kept so that an asset's numbers never change by a rounding)."""

    rotation: np.ndarray
    factors: np.ndarray | float | None
    """Per-axis (size) or uniform (scale) factor, or None for 1."""
    centre: np.ndarray

    def apply(self, vertices: np.ndarray) -> np.ndarray:
        v = np.asarray(vertices, dtype=np.float64) @ self.rotation.T
        if self.factors is not None:
            v = v * self.factors
        return v - self.centre


def frame_transform(
    mesh: trimesh.Trimesh,
    up: str = "y",
    yaw: float = 0.0,
    scale: float | None = None,
    size: Sequence[float] | None = None,
    flip: bool = False,
) -> FrameTransform:
    """The transform `normalize` applies to `mesh` (see there), so that a decimated copy of the
    mesh can be put into exactly the same frame as the full one."""
    rot = yaw_matrix(yaw) @ up_rotation(up, flip)
    v = np.asarray(mesh.vertices, dtype=np.float64) @ rot.T
    factors: np.ndarray | float | None = None
    if size is not None:
        extent = v.max(axis=0) - v.min(axis=0)
        factors = np.asarray(size, dtype=np.float64) / extent
    elif scale is not None:
        factors = float(scale)
    if factors is not None:
        v = v * factors
    lo, hi = v.min(axis=0), v.max(axis=0)
    return FrameTransform(rot, factors, (lo + hi) / 2.0)


def normalize(
    mesh: trimesh.Trimesh,
    up: str = "y",
    yaw: float = 0.0,
    scale: float | None = None,
    size: Sequence[float] | None = None,
    flip: bool = False,
) -> trimesh.Trimesh:
    """Return a new mesh in the asset frame (metres, Z up, facing +Y, bbox centred at 0).

    `scale` multiplies uniformly (e.g. metres per unit of a unit-normalised model); `size`
    instead stretches each axis so the final bbox is exactly `size` (x, y, z) metres, and
    wins when both are given (callers reject that combination as a user error).
    """
    transform = frame_transform(mesh, up, yaw, scale, size, flip)
    return trimesh.Trimesh(transform.apply(mesh.vertices), np.asarray(mesh.faces), process=False)
