"""Foxglove's view of a run log: `foxglove.SceneUpdate` entities for the scene and the character.

Everything is JSON (the log's message encoding) with Foxglove's schema names, so Foxglove's 3D
panel draws the log without extensions:

- one entity per scene object (`scene/<name>`): its mesh embedded as GLB bytes (the asset's
  `vis/mesh.glb`, never a path of the machine that wrote the log), else its bounding box; a
  dynamic object (a box to carry) hangs on its own /tf frame, so it moves with the episode;
- the planned trajectories as line strips, the subtasks' targets as spheres;
- one entity per body of the character (`character/<body>`), frame-locked to the body's /tf
  frame, built from its collision primitives (capsules as cylinders with sphere ends);
- on its own topic /foxglove/task, each recorded frame's task markers
  (`detach.eval.task_markers`: the Follow path done and ahead, the targets, the subtask and
  time, the verdict at the end) as `task/...` entities; each message deletes the previous
  frame's and holds the whole set, so a seek in Foxglove shows the right frame's markers.
"""

from __future__ import annotations

import base64
from pathlib import Path
from typing import Any

from detach.eval.task_markers import Disc, Marker, Polyline, Sphere, Text
from detach.runfolder.messages import SceneMessage

SCENE_UPDATE_TOPIC = "/foxglove/scene"
TASK_UPDATE_TOPIC = "/foxglove/task"
MAX_EMBEDDED_MESH_BYTES = 8 * 1024 * 1024
"""Larger meshes are drawn as their bounding box (a log stays small enough to open)."""

_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
_QUAT = {"type": "object", "properties": {k: {"type": "number"} for k in "xyzw"}}
_POSE = {"type": "object", "properties": {"position": _VEC3, "orientation": _QUAT}}
_COLOR = {"type": "object", "properties": {k: {"type": "number"} for k in "rgba"}}
_TIME = {"type": "object", "properties": {"sec": {"type": "integer"}, "nsec": {"type": "integer"}}}
_SHAPE = {"type": "object", "properties": {"pose": _POSE, "size": _VEC3, "color": _COLOR}}
_ARRAY = lambda item: {"type": "array", "items": item}  # noqa: E731
FOXGLOVE_SCENE_UPDATE = {
    "title": "foxglove.SceneUpdate", "type": "object",
    "properties": {
        "deletions": _ARRAY({"type": "object", "properties": {
            "timestamp": _TIME, "type": {"type": "integer"}, "id": {"type": "string"}}}),
        "entities": _ARRAY({"type": "object", "properties": {
            "timestamp": _TIME, "frame_id": {"type": "string"}, "id": {"type": "string"},
            "lifetime": _TIME, "frame_locked": {"type": "boolean"},
            "metadata": _ARRAY({"type": "object", "properties": {"key": {"type": "string"},
                                                                 "value": {"type": "string"}}}),
            "cubes": _ARRAY(_SHAPE), "spheres": _ARRAY(_SHAPE),
            "cylinders": _ARRAY({"type": "object", "properties": {
                "pose": _POSE, "size": _VEC3, "bottom_scale": {"type": "number"},
                "top_scale": {"type": "number"}, "color": _COLOR}}),
            "lines": _ARRAY({"type": "object", "properties": {
                "type": {"type": "integer"}, "pose": _POSE, "thickness": {"type": "number"},
                "scale_invariant": {"type": "boolean"}, "points": _ARRAY(_VEC3), "color": _COLOR}}),
            "texts": _ARRAY({"type": "object", "properties": {
                "pose": _POSE, "billboard": {"type": "boolean"}, "font_size": {"type": "number"},
                "scale_invariant": {"type": "boolean"}, "color": _COLOR, "text": {"type": "string"}}}),
            "models": _ARRAY({"type": "object", "properties": {
                "pose": _POSE, "scale": _VEC3, "color": _COLOR, "override_color": {"type": "boolean"},
                "url": {"type": "string"}, "media_type": {"type": "string"},
                "data": {"type": "string", "contentEncoding": "base64"}}}),
        }}),
    },
}
LINE_STRIP = 0
DELETE_ALL = 1
"""SceneEntityDeletion type: every entity of the topic."""


def _stamp(time_ns: int) -> dict[str, int]:
    return {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}


def _pose(pos=(0.0, 0.0, 0.0), wxyz=(1.0, 0.0, 0.0, 0.0)) -> dict[str, Any]:
    return {"position": dict(zip("xyz", map(float, pos))),
            "orientation": {"x": float(wxyz[1]), "y": float(wxyz[2]), "z": float(wxyz[3]), "w": float(wxyz[0])}}


def _color(rgb, alpha: float = 1.0) -> dict[str, float]:
    r, g, b = (float(c) / 255 for c in rgb[:3])
    return {"r": r, "g": g, "b": b, "a": alpha}


def _entity(entity_id: str, frame_id: str, time_ns: int, **shapes: Any) -> dict[str, Any]:
    return {"timestamp": _stamp(time_ns), "frame_id": frame_id, "id": entity_id, "lifetime": _stamp(0),
            "frame_locked": frame_id != "world", "metadata": [], **shapes}


def embedded_mesh(mesh: str, assets_root: Path) -> bytes | None:
    """The GLB of an asset named by its mesh path relative to the assets root
    (`<category>/<model_id>/mesh.obj` -> `<category>/<model_id>/vis/mesh.glb`), or None."""
    glb = Path(assets_root) / Path(mesh).parent / "vis" / "mesh.glb"
    try:
        if glb.stat().st_size <= MAX_EMBEDDED_MESH_BYTES:
            return glb.read_bytes()
    except OSError:
        pass
    return None


def _body_shapes(geoms: list[dict[str, Any]]) -> dict[str, list[dict[str, Any]]]:
    """A body's MuJoCo collision primitives as Foxglove shapes in the body frame."""
    shapes: dict[str, list[dict[str, Any]]] = {"spheres": [], "cylinders": [], "cubes": []}
    color = _color((90, 140, 210))
    for g in geoms:
        size, pos, quat = list(g["size"]), list(g["pos"]), list(g["quat"])
        if g["type"] == "sphere":
            d = 2 * size[0]
            shapes["spheres"].append({"pose": _pose(pos, quat), "size": {"x": d, "y": d, "z": d}, "color": color})
        elif g["type"] == "box":
            shapes["cubes"].append({"pose": _pose(pos, quat), "size": dict(zip("xyz", (2 * s for s in size[:3]))),
                                    "color": color})
        elif g["type"] == "capsule":
            r, half = size[0], size[1]
            d = 2 * r
            shapes["cylinders"].append({"pose": _pose(pos, quat), "size": {"x": d, "y": d, "z": 2 * half},
                                        "bottom_scale": 1.0, "top_scale": 1.0, "color": color})
            w, x, y, z = quat  # the capsule's axis is its local z
            axis = (2 * (x * z + w * y), 2 * (y * z - w * x), 1 - 2 * (x * x + y * y))
            for sign in (-1.0, 1.0):
                end = [p + sign * half * a for p, a in zip(pos, axis)]
                shapes["spheres"].append({"pose": _pose(end), "size": {"x": d, "y": d, "z": d}, "color": color})
    return shapes


def scene_update(scene: SceneMessage, assets_root: Path, time_ns: int) -> dict[str, Any]:
    """The `foxglove.SceneUpdate` of a /scene message (see the module doc)."""
    entities = []
    for obj in scene.objects:
        data = embedded_mesh(obj.mesh, assets_root)
        frame = "world" if obj.static else obj.name
        pose = _pose(obj.pos, obj.quat) if obj.static else _pose()
        color = _color((150, 150, 150) if obj.static else (200, 140, 60))
        if data is not None:
            shapes = {"models": [{"pose": pose, "scale": {"x": 1.0, "y": 1.0, "z": 1.0}, "color": color,
                                  "override_color": False, "url": "", "media_type": "model/gltf-binary",
                                  "data": base64.b64encode(data).decode("ascii")}]}
        else:
            shapes = {"cubes": [{"pose": pose, "size": dict(zip("xyz", map(float, obj.bbox))),
                                 "color": {**color, "a": 0.6}}]}
        entity = _entity(f"scene/{obj.name}", frame, time_ns, **shapes)
        entity["metadata"] = [{"key": "category", "value": obj.category}, {"key": "mesh", "value": obj.mesh}]
        entities.append(entity)
    for key, way in scene.trajectories.items():
        points = [dict(zip("xyz", (float(p[0]), float(p[1]), float(p[2]) if len(p) > 2 else 0.02))) for p in way]
        entities.append(_entity(f"trajectory/{key}", "world", time_ns, lines=[{
            "type": LINE_STRIP, "pose": _pose(), "thickness": 0.03, "scale_invariant": False,
            "points": points, "color": _color((40, 160, 70))}]))
    for t in scene.targets:
        entities.append(_entity(f"target/{t.subtask}", "world", time_ns, spheres=[{
            "pose": _pose(t.pos), "size": {"x": 0.15, "y": 0.15, "z": 0.15}, "color": _color(t.color)}]))
    by_body: dict[str, list[dict[str, Any]]] = {}
    for g in scene.body_geoms:
        g = g if isinstance(g, dict) else g.__dict__
        by_body.setdefault(g["body"], []).append(g)
    for body in scene.bodies:
        geoms = by_body.get(body) or [{"type": "sphere", "size": [0.05], "pos": [0, 0, 0], "quat": [1, 0, 0, 0]}]
        entities.append(_entity(f"character/{body}", body, time_ns, **_body_shapes(geoms)))
    return {"deletions": [], "entities": entities}


def task_update(markers: list[Marker], time_ns: int) -> dict[str, Any]:
    """One frame's task markers as a `foxglove.SceneUpdate` (`task/<name>` entities in the world
    frame) that first deletes the previous frame's."""
    entities = []
    for m in markers:
        if isinstance(m, Polyline):
            shapes: dict[str, Any] = {"lines": [{
                "type": LINE_STRIP, "pose": _pose(), "thickness": float(m.width), "scale_invariant": False,
                "points": [dict(zip("xyz", map(float, p))) for p in m.points], "color": _color(m.color)}]}
        elif isinstance(m, Sphere):
            d = 2 * float(m.radius)
            shapes = {"spheres": [{"pose": _pose(m.pos), "size": {"x": d, "y": d, "z": d},
                                   "color": _color(m.color, m.opacity)}]}
        elif isinstance(m, Disc):
            d = 2 * float(m.radius)
            shapes = {"cylinders": [{"pose": _pose((m.pos[0], m.pos[1], 0.01)), "size": {"x": d, "y": d, "z": 0.01},
                                     "bottom_scale": 1.0, "top_scale": 1.0, "color": _color(m.color, m.opacity)}]}
        elif isinstance(m, Text):
            shapes = {"texts": [{"pose": _pose(m.pos), "billboard": True, "font_size": 14.0, "scale_invariant": True,
                                 "color": _color(m.color), "text": m.text}]}
        else:
            continue
        entities.append(_entity(f"task/{m.name}", "world", time_ns, **shapes))
    return {"deletions": [{"timestamp": _stamp(time_ns), "type": DELETE_ALL, "id": ""}], "entities": entities}
