"""Which way is up? Plausibility of an imported object's orientation, with the evidence.

A mesh built with the wrong `--up`, or modelled upside down, goes through the pipeline without
an error: only the height map (it reads an underside) and the targets (centimetres off) are
wrong. This module scores how plausible an orientation is for furniture standing on a floor and
compares the orientation as given with the alternatives, so the pipeline can warn with the
numbers that made it suspicious and `--up auto` can pick the best one.

The rule (measured on the procedural library and on synthetic CAD parts in all orientations, see
tests/test_assets_orientation.py): furniture stands on its feet, legs or a base, with a closed
surface on top, and it is stable. For one orientation (Z up, metres or any unit):
- `support`: area of the support polygon (2D convex hull of the points within 1% of the height
  of the lowest point) / bbox footprint;
- `contact`: fraction of the footprint whose lowest surface lies in that bottom band (seen from
  below), i.e. how much of the support polygon is really touching the floor;
- `top`: fraction of the footprint whose highest surface lies in the top band (seen from above);
- `stable`: the area-weighted centroid of the surface projects inside the support polygon.
Score = (support - contact) * (1 + top) for a stable orientation: open legs below, best with a
closed top above (a table scores ~1.75, the same table upside down ~0.0, a chair on its back
~0.4), and -1 when unstable (a wedge balancing on its edge). A box, or a sofa on a closed skirt,
scores the same in every orientation: no evidence, no warning. Another candidate must beat the
given orientation by `MARGIN` per change (other up axis, turned over) to be warned about or
chosen by `--up auto`; with that the procedural library raises no false warning (a skirted sofa
turned onto its front scores 0.3 over upright: two changes, short of 0.4).

Also reported, as evidence only: the height of the centroid (fraction of the height) and the
largest flat horizontal face (area fraction of the footprint, facing up or down).
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
import trimesh

from scene_builder.heightmap import height_map
from scene_builder.normalize import FLIP, UP_AXES, up_rotation

BAND = 0.01
"""Thickness of the bottom and top bands, as a fraction of the object's height."""
MARGIN = 0.2
"""Score by which another orientation must beat the given one per change (other axis, turned
over) to warn, or for `--up auto` to leave the default."""
UNSTABLE = -1.0
"""Score of an orientation whose centroid is outside its support polygon."""
COVER_RES = 64
"""Resolution of the coverage rasters (a 64 x 64 top-down and bottom-up map)."""


@dataclass(frozen=True)
class Evidence:
    """Orientation measures of one candidate (fractions of the bbox footprint or height)."""

    support: float
    contact: float
    top: float
    stable: bool
    centroid_height: float
    """Height of the area-weighted surface centroid above the lowest point / object height."""
    largest_face: float
    """Area of the largest flat horizontal face / footprint."""
    largest_face_up: bool
    """True when that face faces up."""

    @property
    def score(self) -> float:
        return (self.support - self.contact) * (1.0 + self.top) if self.stable else UNSTABLE

    def describe(self) -> str:
        """One clause of numbers for warnings, e.g. 'support polygon 88%, ...'."""
        facing = "up" if self.largest_face_up else "down"
        return (f"support polygon {self.support:.0%} of the footprint, floor contact {self.contact:.0%}, "
                f"closed top {self.top:.0%}, centroid at {self.centroid_height:.0%} of the height"
                f"{'' if self.stable else ' (outside the support: not stable)'}, "
                f"largest flat face {self.largest_face:.0%} facing {facing}")


def _polygon_area_and_contains(points: np.ndarray, query: np.ndarray) -> tuple[float, bool]:
    """(area of the 2D convex hull of `points`, whether `query` lies inside it)."""
    from scipy.spatial import ConvexHull, QhullError

    if len(points) < 3:
        return 0.0, False
    try:
        hull = ConvexHull(points)
    except (QhullError, ValueError):  # all points on a line: an edge, no polygon
        return 0.0, False
    # hull.equations: normal . x + offset <= 0 inside
    inside = bool(np.all(hull.equations[:, :2] @ query + hull.equations[:, 2] <= 1e-9))
    return float(hull.volume), inside


def _largest_flat_face(mesh: trimesh.Trimesh, band: float) -> tuple[float, bool]:
    """(area of the largest horizontal coplanar region, facing up) grouped by height bands."""
    normals, areas, centres = mesh.face_normals, mesh.area_faces, mesh.triangles_center
    best, best_up = 0.0, True
    for up, mask in ((True, normals[:, 2] > 0.995), (False, normals[:, 2] < -0.995)):
        if not mask.any():
            continue
        level = np.round(centres[mask, 2] / band).astype(np.int64)
        _, inverse = np.unique(level, return_inverse=True)
        area = float(np.bincount(inverse, areas[mask]).max())
        if area > best * 1.0001:
            best, best_up = area, up
    return best, best_up


def evidence(mesh: trimesh.Trimesh, engine: str = "auto") -> Evidence:
    """Measures of `mesh` standing as it is (Z up)."""
    lo, hi = mesh.bounds
    extent = hi - lo
    height = float(extent[2])
    footprint = float(extent[0] * extent[1])
    band = BAND * height
    vertices = np.asarray(mesh.vertices)
    bottom_points = vertices[vertices[:, 2] <= lo[2] + band][:, :2]
    areas = mesh.area_faces
    centroid = (mesh.triangles_center * areas[:, None]).sum(axis=0) / max(float(areas.sum()), 1e-300)
    support, stable = _polygon_area_and_contains(bottom_points, centroid[:2])
    from_above, _ = height_map(mesh, COVER_RES, engine)
    below = mesh.copy()
    below.apply_transform(np.block([[FLIP, np.zeros((3, 1))], [np.zeros((1, 3)), np.ones((1, 1))]]))
    from_below, _ = height_map(below, COVER_RES, engine)
    largest, largest_up = _largest_flat_face(mesh, band)
    return Evidence(
        support=support / footprint,
        contact=float(np.mean(from_below >= height - band)),
        top=float(np.mean(from_above >= height - band)),
        stable=stable,
        centroid_height=float((centroid[2] - lo[2]) / height),
        largest_face=largest / footprint,
        largest_face_up=largest_up,
    )


def rotated(mesh: trimesh.Trimesh, rotation: np.ndarray) -> trimesh.Trimesh:
    """A copy of `mesh` with vertices v -> rotation @ v."""
    return trimesh.Trimesh(np.asarray(mesh.vertices) @ np.asarray(rotation).T, np.asarray(mesh.faces), process=False)


Candidate = tuple[str, bool]
"""(up axis of the source file, turned over)."""


def _name(candidate: Candidate) -> str:
    up, flip = candidate
    return f"{up}{'+flip' if flip else ''}"


@dataclass(frozen=True)
class Orientation:
    """The orientation a build uses and why."""

    up: str
    flip: bool
    chosen: str
    """'given' (--up y/z) or 'auto'."""
    evidence: dict[str, Evidence]
    """Per candidate name ('y', 'y+flip', 'z', 'z+flip')."""
    warnings: tuple[str, ...]

    def as_dict(self) -> dict:
        return {"up": self.up, "flip": self.flip, "chosen": self.chosen,
                "scores": {k: round(e.score, 3) for k, e in self.evidence.items()},
                "evidence": {k: {"support": round(e.support, 3), "contact": round(e.contact, 3),
                                 "top": round(e.top, 3), "stable": e.stable,
                                 "centroid_height": round(e.centroid_height, 3),
                                 "largest_flat_face": round(e.largest_face, 3),
                                 "largest_flat_face_up": e.largest_face_up} for k, e in self.evidence.items()}}


def _best(score: dict[str, float], start: Candidate, allow_unflip: bool = True) -> Candidate:
    """The candidate that beats `start` by the most after paying MARGIN per change (other axis,
    turned over); `start` itself when none beats it."""
    options = [(axis, over) for axis in UP_AXES for over in (False, True) if allow_unflip or over]

    def gain(c: Candidate) -> float:
        changes = (c[0] != start[0]) + (c[1] != start[1])
        return score[_name(c)] - score[_name(start)] - MARGIN * changes

    best = max(options, key=gain)
    return best if gain(best) > 0 else start


def assess(raw: trimesh.Trimesh, up: str, flip: bool, label: str, engine: str = "auto") -> Orientation:
    """Evidence for the four ways a source can stand (y or z up, turned over or not) and the
    decision: `up` 'auto' leaves the default (y, not turned over) only for a candidate that
    beats it by MARGIN per change (other axis, turned over), the best such one (`flip` forces
    turning over); an explicit `up` is kept and warned about, by the same rule, when the
    evidence says otherwise. `raw` is the source mesh in its own axes (decimated is fine)."""
    return decide(measure(raw, engine), up, flip, label)


def measure(raw: trimesh.Trimesh, engine: str = "auto") -> dict[str, Evidence]:
    """Evidence per candidate name ('y', 'y+flip', 'z', 'z+flip') for a source mesh in its own axes."""
    return {_name(c): evidence(rotated(raw, up_rotation(*c)), engine)
            for c in ((axis, over) for axis in UP_AXES for over in (False, True))}


def decide(ev: dict[str, Evidence], up: str, flip: bool, label: str) -> Orientation:
    """The decision of `assess` from already measured evidence."""
    if up not in (*UP_AXES, "auto"):
        raise ValueError(f"up must be 'y', 'z' or 'auto', got {up!r}")
    score = {k: e.score for k, e in ev.items()}
    if up == "auto":
        axis, turn = _best(score, ("y", flip), allow_unflip=not flip)
        return Orientation(axis, turn, "auto", ev, ())
    given = (up, flip)
    better = _best(score, given)
    if better == given:
        return Orientation(up, flip, "given", ev, ())
    problems, fixes = [], []
    if better[0] != up:
        problems.append(f"its up axis is {better[0]}, not {up}")
        fixes.append(f"--up {better[0]}")
    if better[1] != flip:
        problems.append("it is upside down" if not flip else "--flip turned it upside down")
        fixes.append("--flip" if not flip else "no --flip")
    warning = (f"{label}: looks like {' and '.join(problems)}: as built {ev[_name(given)].describe()}; "
               f"with {' '.join(fixes)} {ev[_name(better)].describe()}; rebuild with {' '.join(fixes)} "
               "(or --up auto), and check vis/mesh.glb")
    return Orientation(up, flip, "given", ev, (warning,))
