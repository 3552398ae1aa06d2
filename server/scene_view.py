"""3D view of one run: its /scene message and the humanoid replayed from /episode/bodies.

Frames: world, metres, Z up; quaternions (w, x, y, z) as MuJoCo and viser use them.
The humanoid's geoms (MuJoCo capsules, spheres and boxes in their body frames) are drawn as
three batched meshes that share one unit primitive each: spheres (sphere geoms and the two
caps of every capsule), cylinders (capsule shafts, scaled per axis) and boxes. A frame is
then three array updates inside one `server.atomic()` (a scene node per body would be 15+
messages per frame), so replay stays smooth at 30 fps.
"""

from __future__ import annotations

import os
import re
import zlib
from dataclasses import dataclass
from functools import lru_cache
from pathlib import Path
from typing import Any, Sequence

import numpy as np
import trimesh
import viser

from detach.skills import skill_class
from server.episode import Episode

TARGET_COLOR = (220, 40, 40)
"""Targets of skills this dashboard does not know and whose /scene message names no colour."""
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


def humanoid_instances(body_geoms: Sequence[dict[str, Any]], bodies: Sequence[str]
                       ) -> dict[str, Instances]:
    """Split `body_geoms` (the /scene format) into sphere / cylinder / box instances.

    Without geoms (an older log), every body becomes a 7 cm sphere at its origin.
    """
    rows: dict[str, list[tuple[str, Sequence[float], Sequence[float], Sequence[float]]]] = {
        "sphere": [], "cylinder": [], "box": []}
    ident = (1.0, 0.0, 0.0, 0.0)
    for g in body_geoms:
        size = [float(s) for s in g.get("size", (0.05,))] + [0.0, 0.0]
        pos = np.asarray(g.get("pos", (0.0, 0.0, 0.0)), dtype=float)
        quat = np.asarray(g.get("quat", ident), dtype=float)
        kind, body = g.get("type"), str(g.get("body", ""))
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
def _unit_mesh(kind: str) -> trimesh.Trimesh:
    if kind == "sphere":
        mesh = trimesh.creation.icosphere(subdivisions=2, radius=1.0)
    elif kind == "cylinder":
        mesh = trimesh.creation.cylinder(radius=1.0, height=1.0, sections=20)
    else:
        mesh = trimesh.creation.box(extents=(1.0, 1.0, 1.0))
    mesh.visual.vertex_colors = np.array([*BODY_COLOR, 255], dtype=np.uint8)
    return mesh


# --- furniture meshes -------------------------------------------------------------------------
def find_mesh(path: str | None, run_dir: Path) -> Path | None:
    """The asset mesh a /scene object names (`<category>/<model_id>/mesh.obj`; older logs
    wrote an absolute path, of which only those last three parts count), looked up under the
    assets roots: $DETACH_ASSETS, ./assets and an assets/ folder beside the runs folder. A
    name that would leave its root finds nothing: the dashboard opens no other file."""
    if not path:
        return None
    parts = Path(path).parts[-3:]
    if len(parts) != 3 or parts[-1] != "mesh.obj" or any(p in ("", ".", "..") for p in parts):
        return None
    for root in (os.environ.get("DETACH_ASSETS"), "assets", run_dir.parent.parent / "assets"):
        if not root:
            continue
        base = Path(root).resolve()
        candidate = (base / Path(*parts)).resolve()
        if candidate.is_relative_to(base) and candidate.is_file():
            return candidate
    return None


def target_color(target: dict[str, Any]) -> tuple[int, int, int]:
    """A /scene target's colour: as written, else its skill's, else `TARGET_COLOR`."""
    color = target.get("color")
    if isinstance(color, (list, tuple)) and len(color) == 3:
        return tuple(int(c) for c in color)  # type: ignore[return-value]
    try:
        return skill_class(str(target.get("skill", ""))).color
    except ValueError:
        return TARGET_COLOR


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


def scene_bounds(scene: dict[str, Any]) -> tuple[np.ndarray, np.ndarray]:
    """(min xyz, max xyz) of objects, trajectories and targets; a 4 m square if empty."""
    pts = []
    for o in scene.get("objects", ()):
        c, half = np.asarray(o.get("pos", (0, 0, 0)), float), np.asarray(
            o.get("bbox", (0.5, 0.5, 0.5)), float) / 2
        pts += [c - half, c + half]
    for way in (scene.get("trajectories") or {}).values():
        pts += [np.array([*w[:2], 0.0], float) for w in way]
    pts += [np.asarray(t.get("pos", (0, 0, 0)), float) for t in scene.get("targets", ())]
    if not pts:
        return np.array([-2.0, -2.0, 0.0]), np.array([2.0, 2.0, 2.0])
    a = np.array(pts)
    return a.min(axis=0), a.max(axis=0)


def _list(value: Any) -> list:
    return value if isinstance(value, list) else []


def _node(name: str) -> str:
    return re.sub(r"[^A-Za-z0-9_.-]+", "_", name) or "_"


class SceneView:
    """The drawn scene of one run plus its humanoid; `show` replaces it, `set_frame` moves it."""

    def __init__(self, server: viser.ViserServer) -> None:
        self.server = server
        self._handles: list[Any] = []
        self._objects: dict[str, Any] = {}
        self._batches: dict[str, tuple[Instances, Any]] = {}
        self._label: Any = None
        self._index_cache: tuple[tuple[str, ...], dict[str, np.ndarray]] | None = None
        self._bounds: tuple[np.ndarray, np.ndarray] | None = None
        self._posed = False
        self.notes: list[str] = []

    def clear(self) -> None:
        for h in self._handles:
            try:
                h.remove()
            except Exception:  # noqa: BLE001 - already gone with its parent
                pass
        self._handles, self._objects, self._batches = [], {}, {}
        self._label, self._index_cache, self._posed = None, None, False

    def show(self, scene: dict[str, Any] | None, run_dir: Path) -> list[str]:
        """Draw a /scene message; returns notes for the user (e.g. meshes drawn as boxes).

        A malformed message is drawn as far as it goes and the rest becomes a note: a
        broken log must not stop the dashboard."""
        try:
            return self._show(scene if isinstance(scene, dict) else {}, run_dir)
        except Exception as exc:  # noqa: BLE001
            self.notes.append(f"the /scene message could not be drawn completely ({exc!r:.160})")
            return self.notes

    def check_episode(self, episode: Episode) -> None:
        """Raise ValueError if the frames cannot be drawn (checked once, not per frame)."""
        if episode.pos.shape[1:] != (len(episode.bodies), 3) or \
                episode.quat.shape[1:] != (len(episode.bodies), 4):
            raise ValueError(f"pos/quat shapes {episode.pos.shape}/{episode.quat.shape}")
        if not np.isfinite(episode.pos).all() or not np.isfinite(episode.quat).all():
            raise ValueError("non-finite body poses")

    def _show(self, scene: dict[str, Any], run_dir: Path) -> list[str]:
        self.clear()
        self.notes = []
        lo, hi = self._guard("bounds", scene_bounds, scene) or scene_bounds({})
        centre, size = (lo + hi) / 2, np.maximum(hi - lo, 1.0)
        with self.server.atomic():
            self._handles.append(self.server.scene.add_grid(
                "/run/floor", width=float(np.ceil(size[0] + 4)), height=float(np.ceil(size[1] + 4)),
                position=(float(centre[0]), float(centre[1]), 0.0), cell_size=0.5,
                section_size=1.0, plane_color=(235, 235, 235), plane_opacity=0.6))
            for i, obj in enumerate(_list(scene.get("objects"))):
                self._guard(f"object {i}", self._add_object, i, obj, run_dir)
            trajectories = scene.get("trajectories")
            for key, way in (trajectories.items() if isinstance(trajectories, dict) else ()):
                self._guard(f"trajectory {key}", self._add_trajectory, str(key), way)
            for i, tgt in enumerate(_list(scene.get("targets"))):
                self._guard(f"target {i}", self._add_target, i, tgt)
            if self._guard("body_geoms", self._add_humanoid, scene) is None:
                self._add_humanoid({"bodies": scene.get("bodies") or []})  # spheres at bodies
        self._frame_camera(lo, hi)
        return self.notes

    def _guard(self, what: str, fn, *args):
        """fn(*args), or None plus a note naming the bad part of the message."""
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - a malformed entry is skipped, not fatal
            self.notes.append(f"/scene {what}: skipped ({exc!r:.120})")
            return None

    def _add_trajectory(self, key: str, way: Sequence[Sequence[float]]) -> None:
        pts = np.array([[float(w[0]), float(w[1]), 0.03] for w in way], dtype=np.float32)
        if len(pts) >= 2:
            segs = np.stack([pts[:-1], pts[1:]], axis=1)
            self._handles.append(self.server.scene.add_line_segments(
                f"/run/trajectories/{_node(key)}", segs, TRAJECTORY_COLOR, thickness=0.04))

    def _add_target(self, i: int, tgt: dict[str, Any]) -> None:
        self._handles.append(self.server.scene.add_icosphere(
            f"/run/targets/{i}", radius=0.1, subdivisions=2,
            color=target_color(tgt),
            position=tuple(float(v) for v in tgt.get("pos", (0, 0, 0)))))

    def _add_object(self, i: int, obj: dict[str, Any], run_dir: Path) -> None:
        name = str(obj.get("name", f"object_{i}"))
        node = f"/run/objects/{i}_{_node(name)}"
        pose = dict(position=tuple(float(v) for v in obj.get("pos", (0, 0, 0))),
                    wxyz=tuple(float(v) for v in obj.get("quat", (1, 0, 0, 0))))
        static = bool(obj.get("static", True))
        color = (STATIC_COLORS[zlib.crc32(str(obj.get("category", "")).encode())
                               % len(STATIC_COLORS)]
                 if static else DYNAMIC_COLOR)
        path = find_mesh(obj.get("mesh"), run_dir)
        mesh = load_mesh(path) if path is not None else None
        if mesh is not None:
            handle = self.server.scene.add_mesh_simple(node, mesh[0], mesh[1], color=color,
                                                       flat_shading=True, **pose)
        else:
            bbox = tuple(float(v) for v in obj.get("bbox", (0.3, 0.3, 0.3)))
            handle = self.server.scene.add_box(node, color=color, dimensions=bbox,
                                               opacity=0.55, **pose)
            self.notes.append(f"{name}: mesh {obj.get('mesh') or '(none)'} not found, "
                              f"drawn as its bounding box")
        self._handles.append(handle)
        self._objects[name] = handle

    def _add_humanoid(self, scene: dict[str, Any]) -> bool:
        bodies = [str(b) for b in scene.get("bodies", ())]
        inst = humanoid_instances(scene.get("body_geoms") or (), bodies)  # may raise: first
        for kind, ins in inst.items():
            k = len(ins.bodies)
            handle = self.server.scene.add_batched_meshes_trimesh(
                f"/run/humanoid/{kind}", _unit_mesh(kind),
                batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (k, 1)),
                batched_positions=np.zeros((k, 3)), batched_scales=ins.scale, lod="off",
                visible=False)
            self._batches[kind] = (ins, handle)
            self._handles.append(handle)
        self._label = self.server.scene.add_label("/run/humanoid/label", "", visible=False,
                                                  anchor="bottom-center")
        self._handles.append(self._label)
        return True

    def _frame_camera(self, lo: np.ndarray, hi: np.ndarray) -> None:
        """Point cameras at a new layout; a run with the same layout keeps the user's view."""
        if self._bounds is not None and np.allclose(self._bounds[0], lo) and np.allclose(
                self._bounds[1], hi):
            return
        self._bounds = (lo, hi)
        centre = (lo + hi) / 2
        r = float(max(np.linalg.norm(hi[:2] - lo[:2]) / 2, 2.0))
        look = np.array([centre[0], centre[1], 0.0])
        eye = look + r * np.array([0.15, -1.0, 1.45])  # high enough to see over walls
        eye, look = tuple(float(v) for v in eye), tuple(float(v) for v in look)
        self.server.initial_camera.position = eye
        self.server.initial_camera.look_at = look
        for client in self.server.get_clients().values():
            client.camera.position = eye
            client.camera.look_at = look

    def _indices(self, bodies: Sequence[str]) -> dict[str, np.ndarray]:
        key = tuple(bodies)
        if self._index_cache is None or self._index_cache[0] != key:
            pos = {b: i for i, b in enumerate(bodies)}
            self._index_cache = (key, {k: np.array([pos.get(b, 0) for b in ins.bodies])
                                       for k, (ins, _h) in self._batches.items()})
        return self._index_cache[1]

    def set_frame(self, episode: Episode, i: int, text: str = "") -> None:
        """Pose the humanoid and the dynamic objects at frame `i` (one atomic update)."""
        i = int(np.clip(i, 0, episode.num_frames - 1))
        pos, quat = episode.pos[i], episode.quat[i]
        indices = self._indices(episode.bodies)
        with self.server.atomic():
            for kind, (ins, handle) in self._batches.items():
                p, q = instance_poses(ins, indices[kind], pos, quat)
                handle.batched_positions = p
                handle.batched_wxyzs = q
                if not self._posed:
                    handle.visible = True
            for name, (opos, oquat) in episode.objects.items():
                handle = self._objects.get(name)
                if handle is not None:
                    handle.position = opos[i]
                    handle.wxyz = oquat[i]
            if self._label is not None:
                self._label.position = pos[0] + np.array([0.0, 0.0, 1.0])
                if text and self._label.text != text:
                    self._label.text = text
                if self._label.visible != bool(text):
                    self._label.visible = bool(text)
        self._posed = True
