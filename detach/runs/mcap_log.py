"""A run's MCAP log with its Foxglove twins: the package's writer
(`detach.runfolder.mcap_writer.McapLogWriter`) plus, for Foxglove, /tf with the same body (and
dynamic object) poses as `foxglove.FrameTransforms`, /foxglove/scene with the scene and the
character as `foxglove.SceneUpdate` entities and /foxglove/task with each frame's task markers
(`detach.runs.foxglove`, `detach.eval.task_markers`).
"""

from __future__ import annotations

from pathlib import Path
from typing import Any

from detach.eval.task_markers import PathMemo, task_markers, task_state
from detach.runfolder.mcap_writer import McapLogWriter
from detach.runfolder.messages import EpisodeFrame, SceneMessage
from detach.runfolder.names import TF_TOPIC
from detach.runs.foxglove import FOXGLOVE_SCENE_UPDATE, SCENE_UPDATE_TOPIC, TASK_UPDATE_TOPIC, scene_update, task_update

_VEC3 = {"type": "object", "properties": {k: {"type": "number"} for k in "xyz"}}
FOXGLOVE_FRAME_TRANSFORMS = {
    "title": "foxglove.FrameTransforms", "type": "object",
    "properties": {"transforms": {"type": "array", "items": {
        "type": "object",
        "properties": {
            "timestamp": {"type": "object", "properties": {"sec": {"type": "integer"},
                                                           "nsec": {"type": "integer"}}},
            "parent_frame_id": {"type": "string"}, "child_frame_id": {"type": "string"},
            "translation": _VEC3,
            "rotation": {"type": "object",
                         "properties": {k: {"type": "number"} for k in "xyzw"}}}}}}}


class RunLogWriter(McapLogWriter):
    """A run's log.mcap as training and evaluation write it (one writer per process)."""

    def __init__(self, path: Path, flush_every: int = 30, append: bool = False,
                 metrics_until: int | None = None, assets_root: Path | None = None) -> None:
        """`append`, `metrics_until`: `McapLogWriter`. `assets_root`: where the scene's meshes
        are read to embed them in /foxglove/scene (default: $DETACH_ASSETS or ./assets)."""
        self.assets_root = assets_root
        self._targets: list = []
        """The last logged scene's targets (the task markers of every frame draw them)."""
        self._paths = PathMemo()
        super().__init__(path, flush_every, append, metrics_until, extra_channels=(
            (TF_TOPIC, "foxglove.FrameTransforms", FOXGLOVE_FRAME_TRANSFORMS),
            (SCENE_UPDATE_TOPIC, "foxglove.SceneUpdate", FOXGLOVE_SCENE_UPDATE),
            (TASK_UPDATE_TOPIC, "foxglove.SceneUpdate", FOXGLOVE_SCENE_UPDATE)))

    def after_scene(self, scene: SceneMessage, time_ns: int) -> None:
        """/foxglove/scene, the scene's twin."""
        from scene_builder.assets import default_assets_root

        self._targets = list(scene.targets)
        self.write(SCENE_UPDATE_TOPIC, scene_update(scene, self.assets_root or default_assets_root(), time_ns),
                   time_ns)

    def after_frame(self, frame: EpisodeFrame, data: dict[str, Any], time_ns: int) -> None:
        """The frame's foxglove.FrameTransforms twin on /tf (bodies and dynamic objects) and its
        task markers on /foxglove/task."""
        stamp = {"sec": time_ns // 1_000_000_000, "nsec": time_ns % 1_000_000_000}
        poses = [*zip(frame.bodies, data["pos"], data["quat"]),
                 *((o["name"], o["pos"], o["quat"]) for o in (frame.objects or ()))]
        self.write(TF_TOPIC, {"transforms": [
            {"timestamp": stamp, "parent_frame_id": "world", "child_frame_id": name,
             "translation": {"x": p[0], "y": p[1], "z": p[2]},
             "rotation": {"x": q[1], "y": q[2], "z": q[3], "w": q[0]}}
            for name, p, q in poses]}, time_ns)
        key = (int(frame.episode), int(frame.trial))
        state = task_state(data, data["pos"][0] if data["pos"] else (0.0, 0.0, 0.0), self._paths.update(key, data))
        self.write(TASK_UPDATE_TOPIC, task_update(task_markers(self._targets, state), time_ns), time_ns)
        if frame.outcome:
            self._paths.forget(key)
