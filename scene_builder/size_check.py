"""Scale sanity: is an imported object the size of furniture for a ~1.6 m humanoid?

CAD and scan files come in millimetres, centimetres, inches or unit-normalised coordinates,
and nothing in a mesh file says which. A CAD chair read as metres at 0.16 m across gives
sit and climb targets no humanoid can use, without any error. So every imported object whose
size is not given explicitly (`--size`, a task's `size`) is compared with furniture range,
and a warning suggests the power of ten that would bring it into range.
"""

from __future__ import annotations

import math

import numpy as np

FURNITURE_RANGE = (0.2, 6.0)
"""Metres: the largest side of anything in a room the humanoid interacts with, from a small
step or cushion (0.2-0.5 m) to a wall or a bed (2-5 m)."""
TYPICAL = 1.0
"""Metres: the largest side a suggested scale aims at."""


def suggested_scale(largest: float) -> float:
    """The power of ten that brings a largest side of `largest` closest to TYPICAL metres."""
    return 10.0 ** round(math.log10(TYPICAL / largest))


def size_warning(extents: np.ndarray, label: str, scale: float | None) -> str | None:
    """One-line warning when the largest side of `extents` (metres, after `scale`) is outside
    FURNITURE_RANGE, else None."""
    largest = float(np.max(extents))
    lo, hi = FURNITURE_RANGE
    if lo <= largest <= hi or not largest > 0:
        return None
    dims = " x ".join(f"{e:.3g}" for e in extents)
    factor = suggested_scale(largest) * (scale if scale is not None else 1.0)
    return (f"{label}: {dims} m (largest side {largest:.3g} m) is outside furniture range ({lo:g}-{hi:g} m); "
            f"if the file is not in metres, rebuild with --scale {factor:g} (metres per file unit) "
            "or --size X Y Z (the bbox in metres)")
