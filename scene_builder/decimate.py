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
PRECLUSTER = 1.5
"""Meshes above this many times the cap are vertex-clustered to that many faces before quadric
collapse, so the quadric passes see at most 1.5x the cap: their worst case, a finely
tessellated thin panel, costs ~100 us a face and stalls at ~70% (a 300k-face CAD table took
86 s without this), which is then ~15-25 s at the default cap. Clustering merges everything
within a cell, ~8 mm on a table at 1.5x the default cap: thin panels survive it there, not at
much coarser caps (a panel thinner than the cell becomes a sheet), hence the quadric passes
for the last step."""
CLUSTER_FILL = 0.8
"""Clustering stops once it is within this fraction of the cap (it cannot hit it exactly)."""
STALLED = 0.9
"""A pass that keeps more than this fraction of its input faces has stalled (on a 49k-face CAD
table with fan-capped legs, three stalled passes took 12.7 s): go to clustering."""


@dataclass(frozen=True)
class Decimation:
    """What `decimate` did: face counts before and after (equal when under the cap)."""

    faces_in: int
    faces_out: int
    method: str = "none"
    """The steps, e.g. 'quadric' (fast-simplification), 'clustering+quadric' (far above the
    cap), 'quadric+clustering' (quadric stalled); 'none' under the cap."""

    @property
    def applied(self) -> bool:
        return self.faces_out < self.faces_in

    def as_dict(self) -> dict[str, int | bool]:
        return {"faces_in": self.faces_in, "faces_out": self.faces_out, "applied": self.applied, "method": self.method}


def decimate(mesh: trimesh.Trimesh, max_faces: int, label: str) -> tuple[trimesh.Trimesh, Decimation]:
    """`mesh` itself when it has at most `max_faces` faces, else a decimated copy with at most
    `max_faces` faces. `label` names the source in error messages.

    Time is bounded by the cap, not the source: a mesh above PRECLUSTER x the cap is first
    vertex-clustered to that many faces (O(n log n)), then quadric passes finish (their worst
    case, thin panels tessellated finely, costs ~100 us per face and stalls at ~70%), then
    clustering again if they stalled."""
    faces_in = len(mesh.faces)
    if max_faces < 4:
        raise AssetError(f"{label}: face cap must be at least 4, got {max_faces}")
    if faces_in <= max_faces:
        return mesh, Decimation(faces_in, faces_in)
    out, steps = mesh, []
    if faces_in > PRECLUSTER * max_faces:
        out = _cluster(out, int(PRECLUSTER * max_faces))
        steps.append("clustering")
    if len(out.faces) > max_faces:
        steps.append("quadric")
    for aggression in AGGRESSION:  # one pass can stop short of the target (5.2M -> 129k for a 100k cap)
        before = len(out.faces)
        if before <= max_faces:
            break
        try:
            out = out.simplify_quadric_decimation(face_count=max_faces, aggression=aggression)
        except Exception as e:  # the C++ core reports failures as assorted exceptions
            raise AssetError(f"{label}: decimation from {faces_in} to {max_faces} faces failed "
                             f"({type(e).__name__}: {e})") from None
        if len(out.faces) > STALLED * before:
            break
    if len(out.faces) > max_faces:  # quadric collapse stalled: another pass would too, slowly
        out = _cluster(out, max_faces)
        steps.append("clustering")
    if len(out.faces) == 0:
        raise AssetError(f"{label}: decimation from {faces_in} to {max_faces} faces left no faces")
    return out, Decimation(faces_in, len(out.faces), "+".join(steps))


def _cluster(mesh: trimesh.Trimesh, max_faces: int) -> trimesh.Trimesh:
    """Vertex clustering down to at most `max_faces`: vertices in one cell of a grid merge,
    collapsed faces go. Coarse but fast and guaranteed; the merging is trimesh's
    (`merge_vertices` with 0 digits on coordinates divided by the cell size), only the choice
    of the cell is ours: from the surface area (a surface sampled every h metres has ~2 A / h^2
    triangles), then adjusted by the square root of the count's ratio to the cap until the count
    is under the cap and within CLUSTER_FILL of it (a few steps; at most 12)."""

    def clustered(cell: float) -> trimesh.Trimesh:
        out = trimesh.Trimesh(np.asarray(mesh.vertices) / cell, np.asarray(mesh.faces), process=False)
        out.merge_vertices(digits_vertex=0)
        out.update_faces(out.nondegenerate_faces())
        out.update_faces(out.unique_faces())
        out.remove_unreferenced_vertices()
        out.vertices = out.vertices * cell
        return out

    cell = max(float(np.sqrt(2.0 * float(mesh.area) / max_faces)), float(mesh.scale) * 1e-6)
    best: trimesh.Trimesh | None = None
    for _ in range(12):  # a secant-like search on the cell size for a count just under the cap
        out = clustered(cell)
        count = len(out.faces)
        if 0 < count <= max_faces:
            if best is None or count > len(best.faces):
                best = out
            if count >= CLUSTER_FILL * max_faces:
                break
            cell *= min(0.98, float(np.sqrt(count / max_faces)) * 1.02)  # finer, towards the cap
        else:
            cell *= max(1.05, float(np.sqrt(count / max_faces))) if count else 0.5
    if best is not None:
        return best
    return mesh.convex_hull  # not reached in practice: the cell grows at least 5% a step
