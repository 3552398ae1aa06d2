"""Interaction targets read off the height map (the paper: sit 0.1 m above the surface, climb on it).

Both are in the object frame (relative to the bbox centre, metres), x = y = 0. The surface
height is the single centre cell h[64, 64] of the 128x128 map, no averaging: on the procedural
seats that cell is well inside the seat, and a single cell keeps the formula exact for tests
(an axis-aligned box of height c gives sit z = c/2 + 0.1 and climb z = c/2).
"""

from __future__ import annotations

import numpy as np

SIT_OFFSET = 0.1
"""Metres above the seat surface where the pelvis should end up (TokenHSI's tarSitPos)."""


def centre_height(hmap: np.ndarray) -> float:
    """h[64, 64] for a 128x128 map (the cell just past the bbox centre in +X / -Y)."""
    return float(hmap[hmap.shape[0] // 2, hmap.shape[1] // 2])


def sit_target(hmap: np.ndarray, bbox: np.ndarray) -> list[float]:
    """tarSitPos = (0, 0, h + 0.1 - bbox_z / 2)."""
    return [0.0, 0.0, centre_height(hmap) + SIT_OFFSET - float(bbox[2]) / 2.0]


def climb_target(hmap: np.ndarray, bbox: np.ndarray) -> list[float]:
    """tarClimbPos = (0, 0, h - bbox_z / 2): standing on the top surface."""
    return [0.0, 0.0, centre_height(hmap) - float(bbox[2]) / 2.0]
