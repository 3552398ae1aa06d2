"""Collision shapes: CoACD convex decomposition of the processed mesh.

MuJoCo collides each mesh geom through its convex hull, so a concave chair needs several
convex pieces as geoms of one body. CoACD is slow (seconds to minutes), which is why the
result is cached with the asset. Convex inputs (boxes, walls, cushions) skip CoACD: their
hull is the exact decomposition.
"""

from __future__ import annotations

import numpy as np
import trimesh

from scene_builder.errors import AssetError


def convex_hulls(
    mesh: trimesh.Trimesh,
    label: str,
    threshold: float = 0.05,
    max_hulls: int = 16,
    max_hull_vertices: int = 64,
    seed: int = 0,
) -> tuple[list[trimesh.Trimesh], str]:
    """(hulls in the mesh's frame, method 'convex' or 'coacd').

    `threshold` is CoACD's concavity tolerance (smaller = more, tighter hulls); `max_hulls`
    caps the count (CoACD merges beyond it) to keep MuJoCo's contact work bounded;
    `max_hull_vertices` decimates each hull. `label` names the source in error messages.
    Watertight meshes run with CoACD's preprocessing off (measured ~1 s vs ~12 s for a
    manifold chair); others need its manifold remeshing ('auto').
    """
    if mesh.is_watertight and mesh.is_convex:
        return [mesh.convex_hull], "convex"
    import coacd

    coacd.set_log_level("error")
    try:
        parts = coacd.run_coacd(
            coacd.Mesh(np.asarray(mesh.vertices, dtype=np.float64), np.asarray(mesh.faces, dtype=np.int32)),
            threshold=threshold,
            max_convex_hull=max_hulls,
            preprocess_mode="off" if mesh.is_watertight else "auto",
            decimate=True,
            max_ch_vertex=max_hull_vertices,
            seed=seed,
        )
    except Exception as e:  # CoACD reports failures as assorted exceptions from its C++ core
        raise AssetError(f"{label}: CoACD convex decomposition failed ({type(e).__name__}: {e})") from None
    hulls = [trimesh.Trimesh(v, f, process=True) for v, f in parts if len(f) >= 4]
    if not hulls:
        raise AssetError(f"{label}: CoACD convex decomposition returned no hulls")
    return hulls, "coacd"
