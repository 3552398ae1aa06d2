"""Geometry of the 3D view, without a viser server: quaternions, the humanoid as batched
primitives, furniture meshes (found only under an assets root) and scene bounds.

Frames: world, metres, Z up; quaternions (w, x, y, z) as MuJoCo and viser use them.
The humanoid's geoms (MuJoCo capsules, spheres and boxes in their body frames) are drawn as
three batched meshes that share one unit primitive each: spheres (sphere geoms and the two
caps of every capsule), cylinders (capsule shafts, scaled per axis) and boxes.
"""

from __future__ import annotations

import re
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Sequence

import numpy as np
import trimesh

from detach.runfolder.messages import BodyGeom, SceneMessage
from scene_builder.assets import default_assets_root


BODY_COLOR = (222, 170, 120)
STATIC_COLORS = ((150, 150, 160), (175, 160, 140), (140, 165, 150), (165, 150, 175),
                 (160, 175, 185))
DYNAMIC_COLOR = (235, 140, 50)
TRAJECTORY_COLOR = (0, 170, 200)


# --- quaternions (w, x, y, z), vectorised over leading axes ---------------------------------
def quat_mul(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    aw, ax, ay, az = np.moveaxis(a, -1, 0)
    bw, bx, by, bz = np.moveaxis(b, -1, 0)
    return np.stack([aw * bw - ax * bx - ay * by - az * bz,
                     aw * bx + ax * bw + ay * bz - az * by,
                     aw * by - ax * bz + ay * bw + az * bx,
                     aw * bz + ax * by - ay * bx + az * bw], axis=-1)


def quat_rotate(q: np.ndarray, v: np.ndarray) -> np.ndarray:
    """Rotate vectors v [..., 3] by unit quaternions q [..., 4]."""
    w, u = q[..., :1], q[..., 1:]
    t = 2.0 * np.cross(u, v)
    return v + w * t + np.cross(u, t)


# --- the humanoid as batched primitives -----------------------------------------------------
@dataclass
class Instances:
    """Instances of one unit primitive: the body each rides on, its pose in that body's
    frame and its per-axis scale."""

    bodies: list[str]
    pos: np.ndarray
    """[K, 3] in the body frame."""
    quat: np.ndarray
    """[K, 4] in the body frame."""
    scale: np.ndarray
    """[K, 3]."""


def humanoid_instances(body_geoms: Sequence[BodyGeom], bodies: Sequence[str]) -> dict[str, Instances]:
    """Split `body_geoms` (the /scene format) into sphere / cylinder / box instances.

    Without geoms (an older log), every body becomes a 7 cm sphere at its origin.
    """
    rows: dict[str, list[tuple[str, Sequence[float], Sequence[float], Sequence[float]]]] = {
        "sphere": [], "cylinder": [], "box": []}
    ident = (1.0, 0.0, 0.0, 0.0)
    for g in body_geoms:
        size = [*g.size, 0.0, 0.0]
        pos, quat = np.asarray(g.pos, dtype=float), np.asarray(g.quat, dtype=float)
        kind, body = g.type, g.body
        if kind == "sphere":
            rows["sphere"].append((body, pos, ident, (size[0],) * 3))
        elif kind == "capsule":
            r, half = size[0], size[1]
            axis = quat_rotate(quat, np.array([0.0, 0.0, half]))
            rows["cylinder"].append((body, pos, quat, (r, r, 2.0 * half)))
            rows["sphere"].append((body, pos + axis, ident, (r,) * 3))
            rows["sphere"].append((body, pos - axis, ident, (r,) * 3))
        elif kind == "box":
            rows["box"].append((body, pos, quat, tuple(2.0 * s for s in size[:3])))
    if not body_geoms:
        rows["sphere"] = [(b, (0.0, 0.0, 0.0), ident, (0.07,) * 3) for b in bodies]
    return {k: Instances([r[0] for r in v], np.array([r[1] for r in v], dtype=float),
                         np.array([r[2] for r in v], dtype=float),
                         np.array([r[3] for r in v], dtype=float))
            for k, v in rows.items() if v}


def instance_poses(inst: Instances, index: np.ndarray, body_pos: np.ndarray,
                   body_quat: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """World positions [K, 3] and orientations [K, 4] of the instances for one frame;
    `index[k]` is the row of instance k's body in the frame's body arrays."""
    q = body_quat[index]
    return body_pos[index] + quat_rotate(q, inst.pos), quat_mul(q, inst.quat)


@lru_cache(maxsize=3)
def unit_mesh(kind: str) -> trimesh.Trimesh:
    if kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=20)
    else:
        mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    mesh.visual.vertex_colors = np.array([*BODY_COLOR, 255], dtype=np.uint8)
    return mesh


# --- furniture meshes -------------------------------------------------------------------------
def find_mesh(path: str | None, root: Path | None = None) -> Path | None:
    """The asset mesh a /scene object names (`<category>/<model_id>/mesh.obj`; older logs
    wrote an absolute path, of which only those last three parts count), looked up under the
    assets root the CLI builds and trains from (`root`, default `default_assets_root()`:
    $DETACH_ASSETS, else ./assets), so the dashboard draws what a run of that root used. A name
    that would leave the root finds nothing: the dashboard opens no other file."""
    if not path:
        return None
    parts = Path(path).parts[-3:]
    if len(parts) != 3 or parts[-1] != "mesh.obj" or any(p in ("", ".", "..") for p in parts):
        return None
    base = Path(root if root is not None else default_assets_root()).resolve()
    candidate = (base / Path(*parts)).resolve()
    return candidate if candidate.is_relative_to(base) and candidate.is_file() else None


@lru_cache(maxsize=64)
def _load_mesh(path: str, mtime_ns: int) -> tuple[np.ndarray, np.ndarray]:
    mesh = trimesh.load(path, force="mesh", process=False)
    return (np.asarray(mesh.vertices, dtype=np.float32),
            np.asarray(mesh.faces, dtype=np.uint32))


def load_mesh(path: Path) -> tuple[np.ndarray, np.ndarray] | None:
    """(vertices, faces) of a mesh file, cached by path and mtime; None if unloadable."""
    try:
        v, f = _load_mesh(str(path), path.stat().st_mtime_ns)
    except Exception:  # noqa: BLE001 - a broken file is drawn as its bbox instead
        return None
    return (v, f) if len(v) and len(f) else None


def scene_bounds(scene: SceneMessage | None) -> tuple[np.ndarray, np.ndarray]:
    """(min xyz, max xyz) of objects, trajectories and targets; a 4 m square if empty."""
    pts = []
    for o in scene.objects if scene is not None else ():
        c, half = np.asarray(o.pos, float), np.asarray(o.bbox, float) / 2
        pts += [c - half, c + half]
    for way in scene.trajectories.values() if scene is not None else ():
        pts += [np.array([*w[:2], 0.0], float) for w in way]
    pts += [np.asarray(t.pos, float) for t in (scene.targets if scene is not None else ())]
    if not pts:
        return np.array([-2.0, -2.0, 0.0]), np.array([2.0, 2.0, 2.0])
    a = np.array(pts)
    return a.min(axis=0), a.max(axis=0)


def node_name(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "_"
