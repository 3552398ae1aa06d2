"""Top-down height map of an object: 128x128 rays cast straight down over its bounding box.

Layout (docs/ARCHITECTURE.md, "Asset folder"): row 0 is max Y, the last row min Y; column 0 is min X;
values are metres above the object's lowest point of the first surface a downward ray hits,
0 where it hits nothing.

Grids (docs/ASSET_IMPORT.md, "Height-map grids"):
- "centres" (ours, default): rays through the centres of 128 x 128 equal cells of the bbox,
  x = min + (i + 0.5) * extent / 128. Never on the bbox edges, where Embree misses grazing
  rays; at cell centres both engines agree pixel for pixel.
- "linspace" (TokenHSI's `get_heightmap_raytrace`): x = linspace(min, max, 128), the first and
  last rows and columns on the bbox edges. Offered so maps can be compared and exchanged with
  TokenHSI's; the numpy engine hits edge rays exactly, Embree gets its edge rays moved inside
  by `EDGE_INSET` of the extent (it would miss them).

Engines, chosen explicitly (trimesh's `mesh.ray` would pick one silently):
- "embree": trimesh's Embree wrapper (package `embreex`), ~10-25 ms for 128x128.
- "numpy": a vectorised z-buffer written for vertical rays (exact in float64, no extra
  dependency). trimesh's own pure-Python ray engine is not used: it needs `rtree`.
"""

from __future__ import annotations

import numpy as np
import trimesh

from scene_builder.errors import AssetError
from scene_builder.settings import ENGINES, GRIDS, RESOLUTION

__all__ = ["ENGINES", "GRIDS", "RESOLUTION", "embree_available", "grid_points", "height_map", "pick_engine",
           "surface_top"]

EDGE_INSET = 1e-7
"""Fraction of the extent by which Embree's rays on the bbox edges move inside (linspace grid)."""


def embree_available() -> bool:
    try:
        import embreex  # noqa: F401
    except ImportError:
        return False
    return True


def pick_engine(engine: str = "auto") -> str:
    """'auto' -> 'embree' when embreex is installed, else 'numpy'."""
    if engine == "auto":
        return "embree" if embree_available() else "numpy"
    if engine not in ENGINES:
        raise AssetError(f"ray engine: unknown '{engine}' (expected auto, {', '.join(ENGINES)})")
    if engine == "embree" and not embree_available():
        raise AssetError("ray engine: 'embree' requested but the embreex package is not installed")
    return engine


def cell_centres(bounds: np.ndarray, res: int = RESOLUTION) -> tuple[np.ndarray, np.ndarray]:
    """x of each column (ascending from min X) and y of each row (descending from max Y)."""
    (x0, y0, _), (x1, y1, _) = bounds
    xs = x0 + (np.arange(res) + 0.5) * (x1 - x0) / res
    ys = y1 - (np.arange(res) + 0.5) * (y1 - y0) / res
    return xs, ys


def grid_points(bounds: np.ndarray, res: int = RESOLUTION, grid: str = "centres") -> tuple[np.ndarray, np.ndarray]:
    """(x per column ascending from min X, y per row descending from max Y) of a grid convention."""
    if grid == "centres":
        return cell_centres(bounds, res)
    if grid != "linspace":
        raise AssetError(f"height-map grid: unknown '{grid}' (expected {', '.join(GRIDS)})")
    (x0, y0, _), (x1, y1, _) = bounds
    return np.linspace(x0, x1, res), np.linspace(y1, y0, res)


def _top_embree(mesh: trimesh.Trimesh, xs: np.ndarray, ys: np.ndarray) -> np.ndarray:
    from trimesh.ray.ray_pyembree import RayMeshIntersector

    gx, gy = np.meshgrid(xs, ys)  # [row, col]
    origins = np.column_stack([gx.ravel(), gy.ravel(), np.full(gx.size, mesh.bounds[1, 2] + 1.0)])
    dirs = np.tile([0.0, 0.0, -1.0], (gx.size, 1))
    _, ray, loc = RayMeshIntersector(mesh).intersects_id(origins, dirs, multiple_hits=False, return_locations=True)
    top = np.full(gx.size, np.nan)
    top[ray] = loc[:, 2]
    return top.reshape(gx.shape)


def _top_numpy(mesh: trimesh.Trimesh, xs: np.ndarray, ys: np.ndarray, max_pairs: int = 2_000_000) -> np.ndarray:
    """Highest surface point above each cell centre: for every triangle, the cell centres
    inside its XY footprint, barycentric z, max per cell. Works in chunks of triangle-cell
    pairs so long thin triangles spanning the whole map stay within memory."""
    res_x, res_y = len(xs), len(ys)
    dx = (xs[-1] - xs[0]) / max(res_x - 1, 1) if res_x > 1 else 1.0
    dy = (ys[0] - ys[-1]) / max(res_y - 1, 1) if res_y > 1 else 1.0
    tri = np.asarray(mesh.triangles, dtype=np.float64)
    a, e1, e2 = tri[:, 0], tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]
    det = e1[:, 0] * e2[:, 1] - e1[:, 1] * e2[:, 0]
    lo, hi = tri.min(axis=1), tri.max(axis=1)
    c0 = np.clip(np.ceil((lo[:, 0] - xs[0]) / dx - 1e-9), 0, res_x).astype(np.int64)
    c1 = np.clip(np.floor((hi[:, 0] - xs[0]) / dx + 1e-9), -1, res_x - 1).astype(np.int64)
    r0 = np.clip(np.ceil((ys[0] - hi[:, 1]) / dy - 1e-9), 0, res_y).astype(np.int64)
    r1 = np.clip(np.floor((ys[0] - lo[:, 1]) / dy + 1e-9), -1, res_y - 1).astype(np.int64)
    nc, nr = np.maximum(c1 - c0 + 1, 0), np.maximum(r1 - r0 + 1, 0)
    count = nc * nr
    flat_tol = 1e-12 * float(mesh.scale) ** 2  # vertical triangles have no footprint
    tids = np.flatnonzero((count > 0) & (np.abs(det) > flat_tol))
    top = np.full(res_x * res_y, -np.inf)
    ends = np.cumsum(count[tids])
    start = 0
    while start < len(tids):
        base = ends[start - 1] if start else 0
        stop = max(int(np.searchsorted(ends, base + max_pairs, side="right")), start + 1)
        t = tids[start:stop]
        n = count[t]
        tt = np.repeat(t, n)
        k = np.arange(n.sum()) - np.repeat(np.cumsum(n) - n, n)
        col, row = c0[tt] + k % nc[tt], r0[tt] + k // nc[tt]
        px, py = xs[col] - a[tt, 0], ys[row] - a[tt, 1]
        wb = (px * e2[tt, 1] - py * e2[tt, 0]) / det[tt]
        wc = (e1[tt, 0] * py - e1[tt, 1] * px) / det[tt]
        wa = 1.0 - wb - wc
        inside = (wa >= -1e-9) & (wb >= -1e-9) & (wc >= -1e-9)
        z = wa * tri[tt, 0, 2] + wb * tri[tt, 1, 2] + wc * tri[tt, 2, 2]
        np.maximum.at(top, (row * res_x + col)[inside], z[inside])
        start = stop
    top[np.isinf(top)] = np.nan
    return top.reshape(res_y, res_x)


def surface_top(mesh: trimesh.Trimesh, res: int = RESOLUTION, engine: str = "auto", grid: str = "centres",
                bounds: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """(float64 [res, res] world z of the first surface hit, NaN where a ray misses; engine that ran).

    `bounds` ([2, 3], default the mesh's) sets the grid: the pipeline passes the full-resolution
    mesh's bounds when it casts onto a decimated copy, so the grid does not move."""
    engine = pick_engine(engine)
    bounds = np.asarray(mesh.bounds if bounds is None else bounds, dtype=np.float64)
    xs, ys = grid_points(bounds, res, grid)
    if engine == "embree" and grid == "linspace":
        inset_x, inset_y = EDGE_INSET * (xs[-1] - xs[0]), EDGE_INSET * (ys[0] - ys[-1])
        xs, ys = xs.copy(), ys.copy()
        xs[0], xs[-1] = xs[0] + inset_x, xs[-1] - inset_x
        ys[0], ys[-1] = ys[0] - inset_y, ys[-1] + inset_y
    return (_top_embree if engine == "embree" else _top_numpy)(mesh, xs, ys), engine


def heights_from_top(top: np.ndarray, floor_z: float) -> np.ndarray:
    """float32 heights above `floor_z` (the lowest point), 0 where `top` is NaN (a miss)."""
    h = np.where(np.isnan(top), 0.0, top - floor_z)
    return np.maximum(h, 0.0).astype(np.float32)


def height_map(mesh: trimesh.Trimesh, res: int = RESOLUTION, engine: str = "auto", grid: str = "centres",
               bounds: np.ndarray | None = None) -> tuple[np.ndarray, str]:
    """(float32 [res, res] heights in metres above the lowest point, engine that ran)."""
    top, engine = surface_top(mesh, res, engine, grid, bounds)
    floor_z = float((mesh.bounds if bounds is None else np.asarray(bounds))[0, 2])
    return heights_from_top(top, floor_z), engine
