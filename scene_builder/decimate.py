"""Decimation above a face cap, so time and memory follow the cap, not the source file.

Real furniture ranges from a few thousand faces (3D-FUTURE) to millions (CAD exports, scans:
a 2.6M-face mesh took CoACD past 300 s and 10.8 GB). Everything after loading (height maps,
orientation checks, the visual mesh, CoACD) works on a copy decimated to at most `max_faces`
faces with quadric edge collapse from fast-simplification, the maintained decimator that
trimesh's `simplify_quadric_decimation` wraps; we do not write our own. The bbox and the
height-map grid still come from the full-resolution mesh (see pipeline.py), so the numbers an
asset promises (bbox, targets to ~mm) do not drift with decimation.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from scene_builder.errors import AssetError
from scene_builder.settings import HULL_FACES, MAX_FACES

__all__ = ["HULL_FACES", "MAX_FACES", "Decimation", "decimate"]
# MAX_FACES: default face cap of the processed mesh (mesh.obj, height map, orientation check);
# TokenHSI's and 3D-FUTURE's objects are below it, so they are processed exactly as given.
# HULL_FACES: default face cap of CoACD's input (CoACD's time and memory grow with it).
AGGRESSION = (3, 7, 7)
"""fast-simplification's trade-off per pass, 0 (slow, faithful) .. 10 (fast, coarse; 7 is its
default): the first pass faithful (7 bulged a UV sphere's poles by 20%, 3 kept it within 0.2%,
at ~1.4x the time), later passes only finish what it left above the cap. When they still stop
short (fans of 256 thin triangles around a CAD cylinder do not collapse at all), vertex
clustering reaches the cap."""


@dataclass(frozen=True)
class Decimation:
    """What `decimate` did: face counts before and after (equal when under the cap)."""

    faces_in: int
    faces_out: int
    method: str = "none"
    """'none', 'quadric' (fast-simplification) or 'quadric+clustering' (when quadric stalled)."""

    @property
    def applied(self) -> bool:
        return self.faces_out < self.faces_in

    def as_dict(self) -> dict[str, int | bool]:
        return {"faces_in": self.faces_in, "faces_out": self.faces_out, "applied": self.applied, "method": self.method}


def decimate(mesh: trimesh.Trimesh, max_faces: int, label: str) -> tuple[trimesh.Trimesh, Decimation]:
    """`mesh` itself when it has at most `max_faces` faces, else a quadric-decimated copy with
    about `max_faces` faces (never more). `label` names the source in error messages."""
    faces_in = len(mesh.faces)
    if max_faces < 4:
        raise AssetError(f"{label}: face cap must be at least 4, got {max_faces}")
    if faces_in <= max_faces:
        return mesh, Decimation(faces_in, faces_in)
    out, method = mesh, "quadric"
    for aggression in AGGRESSION:  # one pass can stop short of the target (5.2M -> 129k for a 100k cap)
        try:
            out = out.simplify_quadric_decimation(face_count=max_faces, aggression=aggression)
        except Exception as e:  # the C++ core reports failures as assorted exceptions
            raise AssetError(f"{label}: decimation from {faces_in} to {max_faces} faces failed "
                             f"({type(e).__name__}: {e})") from None
        if len(out.faces) <= max_faces:
            break
    else:  # quadric collapse stalled
        out, method = _cluster(out, max_faces), "quadric+clustering"
    if len(out.faces) == 0:
        raise AssetError(f"{label}: decimation from {faces_in} to {max_faces} faces left no faces")
    return out, Decimation(faces_in, len(out.faces), method)


def _cluster(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """Vertex clustering down to at most `max_faces`: vertices in one cell of a grid merge,
    collapsed faces go. Coarse but guaranteed, for when quadric collapse stalls; the merging is
    trimesh's (`merge_vertices` with 0 digits on coordinates divided by the cell size), only the
    bisection on the cell size (16 steps between 1e-4 and 1 times the mesh's scale) is ours."""

    def clustered(cell: float) -> trimesh.Trimesh:
        out = trimesh.Trimesh(np.asarray(mesh.vertices) / cell, np.asarray(mesh.faces), process=False)
        out.merge_vertices(digits_vertex=0)
        out.update_faces(out.nondegenerate_faces())
        out.update_faces(out.unique_faces())
        out.remove_unreferenced_vertices()
        out.vertices = out.vertices * cell
        return out

    lo, hi = np.log(float(mesh.scale) * 1e-4), np.log(float(mesh.scale))
    best = clustered(float(np.exp(hi)))
    for _ in range(16):
        mid = 0.5 * (lo + hi)
        out = clustered(float(np.exp(mid)))
        if len(out.faces) <= max_faces:
            best, hi = out, mid
        else:
            lo = mid
    return best if len(best.faces) > 0 else mesh.convex_hull
