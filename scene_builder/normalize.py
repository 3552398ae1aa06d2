"""Mesh standardisation: any input frame -> metres, Z up, facing +Y, bbox centre at the origin.

Input conventions (the paper's appendix, "mesh standardisation"):
- `up="y"`: 3D-FUTURE's `normalized_model.obj` convention: Y up, the object's front towards +Z.
  A +90 deg rotation about X brings Y up to Z up, but turns that front to -Y, so a 180 deg yaw
  follows; together they are the fixed matrix `Y_UP_TO_Z_UP` below: (x, y, z) -> (-x, z, y).
- `up="z"`: already Z up and facing +Y; only the optional user yaw, scale and recentring apply.
Then an optional extra yaw (degrees, about +Z), then scale (uniform `scale`, or per-axis to an
exact bbox `size` in metres), then recentring on the bounding-box centre.
"""

from __future__ import annotations

from collections.abc import Sequence

import numpy as np
import trimesh

Y_UP_TO_Z_UP = np.array([[-1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, 1.0, 0.0]])
"""Rotation (det +1) = R_z(180 deg) @ R_x(+90 deg): Y-up/front +Z -> Z-up/front +Y."""


def yaw_matrix(degrees: float) -> np.ndarray:
    """Rotation about +Z by `degrees` (counter-clockwise seen from above); exact for k*90."""
    quarter, rest = divmod(float(degrees), 90.0)
    if rest == 0.0:  # exact integers so a 90 deg yaw does not blur the bbox by 1e-17
        c, s = [(1, 0), (0, 1), (-1, 0), (0, -1)][int(quarter) % 4]
    else:
        c, s = np.cos(np.radians(degrees)), np.sin(np.radians(degrees))
    return np.array([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=float)


def normalize(
    mesh: trimesh.Trimesh,
    up: str = "y",
    yaw: float = 0.0,
    scale: float | None = None,
    size: Sequence[float] | None = None,
) -> trimesh.Trimesh:
    """Return a new mesh in the asset frame (metres, Z up, facing +Y, bbox centred at 0).

    `scale` multiplies uniformly (e.g. metres per unit of a unit-normalised model); `size`
    instead stretches each axis so the final bbox is exactly `size` (x, y, z) metres, and
    wins when both are given (callers reject that combination as a user error).
    """
    if up not in ("y", "z"):
        raise ValueError(f"up must be 'y' or 'z', got {up!r}")
    rot = yaw_matrix(yaw) @ (Y_UP_TO_Z_UP if up == "y" else np.eye(3))
    v = np.asarray(mesh.vertices, dtype=np.float64) @ rot.T
    if size is not None:
        extent = v.max(axis=0) - v.min(axis=0)
        v = v * (np.asarray(size, dtype=np.float64) / extent)
    elif scale is not None:
        v = v * float(scale)
    lo, hi = v.min(axis=0), v.max(axis=0)
    v = v - (lo + hi) / 2.0
    return trimesh.Trimesh(v, np.asarray(mesh.faces), process=False)
