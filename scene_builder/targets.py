"""Interaction targets read off the height map (the paper: sit 0.1 m above the surface, climb on it).

Both are in the object frame (relative to the bbox centre, metres). The surface height is the
single centre cell h[64, 64] of the 128x128 map, no averaging: on the procedural seats that
cell is well inside the seat, and a single cell keeps the formula exact for tests (an
axis-aligned box of height c gives sit (0, 0, c/2 + 0.1) and climb (0, 0, c/2)), as in TokenHSI.

When the ray through the centre cell hits nothing (two parts with a gap between them, a ring),
the targets would sit on the floor. Then the target cell is the supporting cell nearest to the
centre (distance in metres): the centre of a flat patch, all hits within `FLAT_TOLERANCE` of
each other, of `PATCH_SIZES[0]` metres on a side (room for a pelvis or both feet), or failing
that of the next smaller size; failing all, the nearest hit. The targets then carry that cell's
x, y and the pipeline warns.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SIT_OFFSET = 0.1
"""Metres above the seat surface where the pelvis should end up (TokenHSI's tarSitPos)."""
PATCH_SIZES = (0.2, 0.1, 0.0)
"""Metres: sides of the flat patch a supporting cell is the centre of, tried in this order
(0.0 = the cell and its 8 neighbours)."""
FLAT_TOLERANCE = 0.02
"""Metres of height variation allowed within a patch."""


def centre_height(hmap: np.ndarray) -> float:
    """h[64, 64] for a 128x128 map (the cell just past the bbox centre in +X / -Y)."""
    return float(hmap[hmap.shape[0] // 2, hmap.shape[1] // 2])


def sit_target(hmap: np.ndarray, bbox: np.ndarray) -> list[float]:
    """tarSitPos = (0, 0, h + 0.1 - bbox_z / 2)."""
    return [0.0, 0.0, centre_height(hmap) + SIT_OFFSET - float(bbox[2]) / 2.0]


def climb_target(hmap: np.ndarray, bbox: np.ndarray) -> list[float]:
    """tarClimbPos = (0, 0, h - bbox_z / 2): standing on the top surface."""
    return [0.0, 0.0, centre_height(hmap) - float(bbox[2]) / 2.0]


@dataclass(frozen=True)
class TargetCell:
    """The map cell the targets stand on."""

    row: int
    col: int
    x: float
    """Object frame, metres (cell position relative to the bbox centre)."""
    y: float
    height: float
    """Height map value there, metres above the lowest point."""
    moved: bool
    """True when the centre cell missed and a nearby supporting cell was used."""
    supporting: bool
    """False when no flat patch exists anywhere and the nearest hit was used."""

    def sit(self, bbox: np.ndarray) -> list[float]:
        return [self.x, self.y, self.height + SIT_OFFSET - float(bbox[2]) / 2.0]

    def climb(self, bbox: np.ndarray) -> list[float]:
        return [self.x, self.y, self.height - float(bbox[2]) / 2.0]


def supporting_cells(hmap: np.ndarray, hit: np.ndarray, cells: tuple[int, int]) -> np.ndarray:
    """bool [R, C]: cells at the centre of a `cells` (rows, cols) patch that lies inside the map,
    is all hits and is flat within FLAT_TOLERANCE."""
    from scipy import ndimage

    high = ndimage.maximum_filter(np.where(hit, hmap, np.inf), size=cells, mode="constant", cval=np.inf)
    low = ndimage.minimum_filter(np.where(hit, hmap, -np.inf), size=cells, mode="constant", cval=-np.inf)
    return hit & (high - low <= FLAT_TOLERANCE)


def target_cell(hmap: np.ndarray, hit: np.ndarray, xs: np.ndarray, ys: np.ndarray) -> TargetCell | None:
    """The cell the targets use: the centre cell when its ray hit something, else the nearest
    supporting cell (else the nearest hit). `xs` / `ys` are the grid's column / row positions
    in the object frame (metres). None when nothing was hit at all."""
    r, c = hmap.shape[0] // 2, hmap.shape[1] // 2
    if hit[r, c]:
        return TargetCell(r, c, 0.0, 0.0, float(hmap[r, c]), moved=False, supporting=True)
    hmap = hmap.astype(np.float64)
    pitch = (abs(xs[-1] - xs[0]) / max(len(xs) - 1, 1), abs(ys[0] - ys[-1]) / max(len(ys) - 1, 1))
    candidates, supporting = hit, False
    for size in PATCH_SIZES:
        cells = tuple(max(3, 2 * int(round(size / max(p, 1e-12) / 2)) + 1) for p in (pitch[1], pitch[0]))
        found = supporting_cells(hmap, hit, cells)  # type: ignore[arg-type]
        if found.any():
            candidates, supporting = found, True
            break
    if not candidates.any():
        return None
    rows, cols = np.nonzero(candidates)
    mid_x, mid_y = 0.5 * (xs[0] + xs[-1]), 0.5 * (ys[0] + ys[-1])
    k = int(np.argmin((xs[cols] - mid_x) ** 2 + (ys[rows] - mid_y) ** 2))
    r, c = int(rows[k]), int(cols[k])
    return TargetCell(r, c, float(xs[c] - mid_x), float(ys[r] - mid_y), float(hmap[r, c]), moved=True,
                      supporting=supporting)
