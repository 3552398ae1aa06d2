"""The 3D view of one browser: up to two runs side by side, each with its replayed character.

Everything is drawn through the client's own scene API, so each browser sees the runs it
chose. A run's scene hangs under one frame node per slot ('a', and 'b' for the run compared
with it), placed beside each other by moving that frame only. A replay frame is three
batched-mesh updates (plus dynamic objects and a label) inside one `atomic()`, so replay
stays smooth at 30 fps; a frame node per body would be 15+ messages per frame.
"""

from __future__ import annotations

import zlib
from typing import Any, Callable, ContextManager, Sequence

import numpy as np

from detach import Marker, Text, task_markers
from detach.runfolder.messages import SceneMessage, SceneObject, SceneTarget
from server.episode import Episode
from server.marker_view import MarkerView
from server.scene_geometry import (
    DYNAMIC_COLOR, STATIC_COLORS, TRAJECTORY_COLOR, Instances, find_mesh, humanoid_instances, instance_poses,
    load_mesh, node_name, scene_bounds, unit_mesh,
)

TRAIL_COLOR = (230, 90, 30)
"""The path the character actually walked (the planned one is TRAJECTORY_COLOR)."""
GAP = 2.0
"""Metres between two runs shown side by side."""


def check_episode(episode: Episode) -> None:
    """Raise ValueError if the frames cannot be drawn (checked once, not per frame)."""
    if episode.pos.shape[1:] != (len(episode.bodies), 3) or \
            episode.quat.shape[1:] != (len(episode.bodies), 4):
        raise ValueError(f"pos/quat shapes {episode.pos.shape}/{episode.quat.shape}")
    if not np.isfinite(episode.pos).all() or not np.isfinite(episode.quat).all():
        raise ValueError("non-finite body poses")


def trail_points(episode: Episode, upto: int | None = None) -> np.ndarray:
    """[K, 2, 3] segments of the root body's ground track (z a little above the floor)."""
    end = episode.num_frames if upto is None else int(np.clip(upto + 1, 0, episode.num_frames))
    pts = np.asarray(episode.pos[:end, 0, :], dtype=np.float32).copy()
    pts[:, 2] = 0.05
    if len(pts) < 2:
        return np.zeros((0, 2, 3), dtype=np.float32)
    return np.stack([pts[:-1], pts[1:]], axis=1)


class RunScene:
    """One run's /scene message and character under the frame `/<slot>`."""

    def __init__(self, scene_api: Any, atomic: Callable[[], ContextManager[None]], slot: str) -> None:
        self.scene, self.atomic, self.slot = scene_api, atomic, slot
        self._root: Any = None
        self._handles: list[Any] = []
        self._objects: dict[str, Any] = {}
        self._batches: dict[str, tuple[Instances, Any]] = {}
        self._label: Any = None
        self._trail: Any = None
        self._targets: list[Any] = []
        self.targets: list[SceneTarget] = []
        """The /scene message's well-formed targets (the task markers draw them)."""
        self.markers = MarkerView(scene_api, f"/{slot}/task")
        self._index_cache: tuple[tuple[str, ...], dict[str, np.ndarray]] | None = None
        self._character_shown = False
        self.bounds: tuple[np.ndarray, np.ndarray] = scene_bounds(None)
        self.offset = np.zeros(3)
        self.notes: list[str] = []
        self.shown = False

    # --- the scene ----------------------------------------------------------------------
    def clear(self) -> None:
        self.markers.clear()
        for h in [*self._handles, self._trail, self._root]:
            if h is None:
                continue
            try:
                h.remove()
            except Exception:  # noqa: BLE001 - already gone with its parent
                pass
        self._root, self._handles, self._objects, self._batches = None, [], {}, {}
        self._label, self._trail, self._index_cache = None, None, None
        self._targets, self.targets = [], []
        self._character_shown = self.shown = False

    def show(self, scene: SceneMessage | None, offset: np.ndarray, notes: Sequence[str] = ()) -> list[str]:
        """Draw a /scene message (None: the floor alone); returns notes for the user: `notes`
        (the parts `SceneMessage.salvage` left out of a malformed message) and what could not
        be drawn (e.g. meshes drawn as boxes). A broken log must not stop the dashboard."""
        self.clear()
        self.notes = list(notes)
        try:
            self._show(scene or SceneMessage("", [], {}, [], [], []), offset)
        except Exception as exc:  # noqa: BLE001
            self.notes.append(f"the /scene message could not be drawn completely ({exc!r:.160})")
        self.shown = True
        return self.notes

    def move(self, offset: np.ndarray) -> None:
        self.offset = np.asarray(offset, dtype=float)
        if self._root is not None:
            self._root.position = tuple(float(v) for v in self.offset)

    def _show(self, scene: SceneMessage, offset: np.ndarray) -> None:
        self.bounds = scene_bounds(scene)
        self.offset = np.asarray(offset, dtype=float)
        lo, hi = self.bounds
        centre, size = (lo + hi) / 2, np.maximum(hi - lo, 1.0)
        base = f"/{self.slot}"
        with self.atomic():
            self._root = self.scene.add_frame(base, show_axes=False,
                                              position=tuple(float(v) for v in self.offset))
            self._handles.append(self.scene.add_grid(
                f"{base}/floor", width=float(np.ceil(size[0] + 4)),
                height=float(np.ceil(size[1] + 4)),
                position=(float(centre[0]), float(centre[1]), 0.0), cell_size=0.5,
                section_size=1.0, plane_color=(235, 235, 235), plane_opacity=0.6))
            for i, obj in enumerate(scene.objects):
                self._guard(f"object {i}", self._add_object, i, obj)
            for key, way in scene.trajectories.items():
                self._guard(f"trajectory {key}", self._add_trajectory, key, way)
            for i, tgt in enumerate(scene.targets):
                self._add_target(i, tgt)
            self.targets = list(scene.targets)
            self._add_character(scene)

    def _guard(self, what: str, fn, *args):
        """fn(*args), or None plus a note naming the bad part of the message."""
        try:
            return fn(*args)
        except Exception as exc:  # noqa: BLE001 - a malformed entry is skipped, not fatal
            self.notes.append(f"/scene {what}: skipped ({exc!r:.120})")
            return None

    def _add_trajectory(self, key: str, way: Sequence[Sequence[float]]) -> None:
        pts = np.array([[w[0], w[1], 0.03] for w in way], dtype=np.float32)
        if len(pts) >= 2:
            segs = np.stack([pts[:-1], pts[1:]], axis=1)
            self._handles.append(self.scene.add_line_segments(
                f"/{self.slot}/trajectories/{node_name(key)}", segs, TRAJECTORY_COLOR,
                thickness=0.04))

    def _add_target(self, i: int, tgt: SceneTarget) -> None:
        handle = self.scene.add_icosphere(
            f"/{self.slot}/targets/{i}", radius=0.1, subdivisions=2, color=tuple(tgt.color),
            position=tuple(tgt.pos))
        self._handles.append(handle)
        self._targets.append(handle)

    def _add_object(self, i: int, obj: SceneObject) -> None:
        node = f"/{self.slot}/objects/{i}_{node_name(obj.name)}"
        pose = dict(position=tuple(obj.pos), wxyz=tuple(obj.quat))
        color = (STATIC_COLORS[zlib.crc32(obj.category.encode()) % len(STATIC_COLORS)] if obj.static
                 else DYNAMIC_COLOR)
        path = find_mesh(obj.mesh)
        mesh = load_mesh(path) if path is not None else None
        if mesh is not None:
            handle = self.scene.add_mesh_simple(node, mesh[0], mesh[1], color=color,
                                                flat_shading=True, **pose)
        else:
            handle = self.scene.add_box(node, color=color, dimensions=tuple(obj.bbox), opacity=0.55, **pose)
            self.notes.append(f"{obj.name}: mesh {obj.mesh or '(none)'} not found, "
                              f"drawn as its bounding box")
        self._handles.append(handle)
        self._objects[obj.name] = handle

    def _add_character(self, scene: SceneMessage) -> None:
        inst = humanoid_instances(scene.body_geoms, scene.bodies)
        for kind, ins in inst.items():
            k = len(ins.bodies)
            handle = self.scene.add_batched_meshes_trimesh(
                f"/{self.slot}/character/{kind}", unit_mesh(kind),
                batched_wxyzs=np.tile([1.0, 0.0, 0.0, 0.0], (k, 1)),
                batched_positions=np.zeros((k, 3)), batched_scales=ins.scale, lod="off",
                visible=False)
            self._batches[kind] = (ins, handle)
            self._handles.append(handle)
        self._label = self.scene.add_label(f"/{self.slot}/character/label", "", visible=False,
                                           anchor="bottom-center")
        self._handles.append(self._label)

    # --- the character ----------------------------------------------------------------------
    def _indices(self, bodies: Sequence[str]) -> dict[str, np.ndarray]:
        key = tuple(bodies)
        if self._index_cache is None or self._index_cache[0] != key:
            pos = {b: i for i, b in enumerate(bodies)}
            self._index_cache = (key, {k: np.array([pos.get(b, 0) for b in ins.bodies])
                                       for k, (ins, _h) in self._batches.items()})
        return self._index_cache[1]

    def set_frame(self, episode: Episode, i: int, text: str = "") -> np.ndarray:
        """Pose the character and the dynamic objects at frame `i`; returns the root body's
        world position (with this slot's offset) for a camera that follows it."""
        i = int(np.clip(i, 0, episode.num_frames - 1))
        pos, quat = episode.pos[i], episode.quat[i]
        indices = self._indices(episode.bodies)
        with self.atomic():
            for kind, (ins, handle) in self._batches.items():
                p, q = instance_poses(ins, indices[kind], pos, quat)
                handle.batched_positions = p
                handle.batched_wxyzs = q
                if not self._character_shown:
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
        self._character_shown = True
        return pos[0] + self.offset

    def set_markers(self, markers: list[Marker]) -> None:
        """Draw a frame's task markers (`detach.eval.task_markers`); while they are shown they
        draw the scene's targets, so the plain target spheres are hidden."""
        with self.atomic():
            self.markers.show(markers)
            for h in self._targets:
                if h.visible != (not markers):
                    h.visible = not markers

    def frame_markers(self, episode: Episode, i: int, caption_prefix: str = "") -> list[Marker]:
        """The task markers of frame `i` of `episode` (none for a log without task data)."""
        i = int(np.clip(i, 0, episode.num_frames - 1))
        if i >= len(episode.task):
            return []
        markers = task_markers(self.targets, episode.task[i])
        if caption_prefix:
            markers = [Text(m.name, caption_prefix + m.text, m.pos, m.color) if isinstance(m, Text) else m
                       for m in markers]
        return markers

    def hide_character(self) -> None:
        """No episode to show: nothing of the previous one may stay on screen."""
        self.set_markers([])
        with self.atomic():
            for _ins, handle in self._batches.values():
                handle.visible = False
            if self._label is not None:
                self._label.visible = False
                self._label.text = ""
            self.set_trail(None)
        self._character_shown = False

    def set_trail(self, episode: Episode | None) -> None:
        """Draw the path the character walked in `episode` (None removes it)."""
        if self._trail is not None:
            try:
                self._trail.remove()
            except Exception:  # noqa: BLE001
                pass
            self._trail = None
        if episode is None or self._root is None:
            return
        segs = trail_points(episode)
        if len(segs):
            self._trail = self.scene.add_line_segments(f"/{self.slot}/trail", segs, TRAIL_COLOR,
                                                       thickness=0.03)

    @property
    def character_shown(self) -> bool:
        return self._character_shown


class SceneView:
    """The 3D view of one client: run A, optionally run B beside it, and its camera."""

    def __init__(self, client: Any) -> None:
        self.client = client
        self.a = RunScene(client.scene, client.atomic, "a")
        self.b = RunScene(client.scene, client.atomic, "b")
        self._framed: tuple[np.ndarray, np.ndarray] | None = None

    def show(self, slot: str, scene: Any) -> list[str]:
        """Draw a run's /scene message as read from its log (`scene`: the JSON object, salvaged
        with `SceneMessage.salvage`) in slot 'a' or 'b' (B sits to the right of A); frames the
        camera when the layout changed, so a run with the same layout keeps the user's view."""
        target = self.a if slot == "a" else self.b
        message, salvaged = SceneMessage.salvage(scene) if scene is not None else (None, [])
        notes = target.show(message, np.zeros(3), salvaged)
        self.place_b()
        self.frame_camera()
        return notes

    def remove(self, slot: str) -> None:
        (self.a if slot == "a" else self.b).clear()
        self.frame_camera()

    def place_b(self) -> None:
        if not self.b.shown:
            return
        lo_a, hi_a = self.a.bounds if self.a.shown else (np.zeros(3), np.zeros(3))
        lo_b, hi_b = self.b.bounds
        offset = np.array([hi_a[0] - lo_b[0] + GAP,
                           (lo_a[1] + hi_a[1]) / 2 - (lo_b[1] + hi_b[1]) / 2, 0.0])
        self.b.move(offset)

    def bounds(self) -> tuple[np.ndarray, np.ndarray]:
        shown = [s for s in (self.a, self.b) if s.shown]
        if not shown:
            return scene_bounds(None)
        los = [s.bounds[0] + s.offset for s in shown]
        his = [s.bounds[1] + s.offset for s in shown]
        return np.min(los, axis=0), np.max(his, axis=0)

    def frame_camera(self) -> None:
        lo, hi = self.bounds()
        if self._framed is not None and np.allclose(self._framed[0], lo) and \
                np.allclose(self._framed[1], hi):
            return
        self._framed = (lo, hi)
        centre = (lo + hi) / 2
        r = float(max(np.linalg.norm(hi[:2] - lo[:2]) / 2, 2.0))
        look = np.array([centre[0], centre[1], 0.0])
        eye = look + r * np.array([0.15, -1.0, 1.45])  # high enough to see over walls
        self.client.camera.position = tuple(float(v) for v in eye)
        self.client.camera.look_at = tuple(float(v) for v in look)

    def follow(self, point: np.ndarray) -> None:
        """Keep the camera's offset from what it looks at, and look at `point`."""
        camera = self.client.camera
        offset = np.asarray(camera.position) - np.asarray(camera.look_at)
        look = np.array([point[0], point[1], 0.9])
        camera.look_at = tuple(float(v) for v in look)
        camera.position = tuple(float(v) for v in look + offset)
