"""A run's MCAP log: the contract's JSON messages on its topics, readable up to a crash.

Topics and message types: `detach.run_contract` (/metrics `MetricsMessage`, /scene
`SceneMessage`, /episode/bodies `EpisodeFrame`), plus for Foxglove /tf with the same body (and
dynamic object) poses as `foxglove.FrameTransforms`, /foxglove/scene with the scene and the
character as `foxglove.SceneUpdate` entities and /foxglove/task with each frame's task markers
(`detach.runs.foxglove`, `detach.eval.task_markers`). Chunks are flushed after
every metrics message and every `flush_every` frames, so a crashed run's log reads up to its
last flush.

Log times are wall-clock: /metrics and /scene at the moment they are written; a recorded
episode's frames at its own place on the timeline, `origin + frame.time`, where each recorded
(episode, trial) gets its own slot of `episode_slot_s` seconds after the previous recordings, so
the evaluation's trials play one after another in Foxglove instead of all starting at t = 0.
"""

from __future__ import annotations

import contextlib
import json
import os
import secrets
import time
from pathlib import Path
from typing import Any, BinaryIO, Iterator, Sequence

from mcap.reader import NonSeekingReader
from mcap.writer import CompressionType, Writer

from detach.eval.task_markers import PathMemo, task_markers, task_state
from detach.runs.foxglove import FOXGLOVE_SCENE_UPDATE, SCENE_UPDATE_TOPIC, TASK_UPDATE_TOPIC, scene_update, task_update
from detach.run_contract import (
    EPISODE_TOPIC, MCAP_SCHEMAS, METRICS_TOPIC, SCENE_TOPIC, TEMP_SUFFIX, TF_TOPIC, EpisodeFrame, MetricsMessage,
    SceneMessage,
)

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


class RunLogWriter:
    """Append-only writer of a run's log.mcap (one writer per process)."""

    episode_slot_s = 60.0
    """Timeline room per recorded trial (episodes are capped at 40 s in the shipped tasks)."""

    def __init__(self, path: Path, flush_every: int = 30, append: bool = False,
                 metrics_until: int | None = None, assets_root: Path | None = None) -> None:
        """`append=True` keeps the messages of an existing log (a resumed run): MCAP files
        cannot be appended to, so they are copied into a fresh file that replaces it.
        `metrics_until` (the resumed checkpoint's iteration) drops the /metrics messages of
        later iterations: the run trains them again, and a log must hold each iteration once.
        `assets_root`: where the scene's meshes are read to embed them in /foxglove/scene
        (default: $DETACH_ASSETS or ./assets)."""
        self.path = Path(path)
        self.assets_root = assets_root
        self._origins: dict[tuple[int, int], int] = {}
        self._episode_base: dict[int, int] = {}
        self._timeline_end = 0
        tmp = self.path.with_name(f".{self.path.name}.{os.getpid()}.{secrets.token_hex(4)}{TEMP_SUFFIX}")
        self._file: BinaryIO = open(tmp, "wb")
        self._writer = Writer(self._file, chunk_size=256 * 1024,
                              compression=CompressionType.ZSTD)
        self._writer.start(profile="", library="detach")
        self._channels: dict[str, int] = {}
        for topic, schema in MCAP_SCHEMAS.items():
            self._channels[topic] = self._register(topic, schema["title"], schema)
        self._channels[TF_TOPIC] = self._register(TF_TOPIC, "foxglove.FrameTransforms",
                                                  FOXGLOVE_FRAME_TRANSFORMS)
        self._channels[SCENE_UPDATE_TOPIC] = self._register(SCENE_UPDATE_TOPIC, "foxglove.SceneUpdate",
                                                            FOXGLOVE_SCENE_UPDATE)
        self._channels[TASK_UPDATE_TOPIC] = self._register(TASK_UPDATE_TOPIC, "foxglove.SceneUpdate",
                                                           FOXGLOVE_SCENE_UPDATE)
        self._targets: list = []
        """The last logged scene's targets (the task markers of every frame draw them)."""
        self._paths = PathMemo()
        self._frames_since_flush = 0
        self.flush_every = flush_every
        self._sequence = 0
        try:
            if append and self.path.exists():
                self._copy_messages(self.path, metrics_until)
            self._writer.flush()
            os.replace(tmp, self.path)
        except BaseException:
            self._file.close()
            Path(tmp).unlink(missing_ok=True)
            raise

    def _copy_messages(self, old: Path, metrics_until: int | None) -> None:
        """Every message of the `old` log, in file order, its bytes passed through: decoding
        and re-encoding each as JSON took 128 s of a 141 s evaluation of a run with a 247 MB
        log. Only /metrics messages are read, and only to drop iterations past
        `metrics_until`."""
        for topic, time_ns, data in iter_raw_messages(old):
            if topic not in self._channels:
                continue
            if metrics_until is not None and topic == METRICS_TOPIC and _iteration(json.loads(data)) > metrics_until:
                continue
            self.write_raw(topic, data, time_ns)
            self._timeline_end = max(self._timeline_end, time_ns)

    def _register(self, topic: str, name: str, schema: dict[str, Any]) -> int:
        schema_id = self._writer.register_schema(name=name, encoding="jsonschema",
                                                 data=json.dumps(schema).encode())
        return self._writer.register_channel(topic=topic, message_encoding="json",
                                             schema_id=schema_id)

    def write(self, topic: str, data: dict[str, Any], time_ns: int) -> None:
        """One JSON message on a registered topic (the typed `log_*` methods below are what
        runs use; tools and tests may write any message)."""
        self.write_raw(topic, json.dumps(data, separators=(",", ":")).encode(), time_ns)

    def write_raw(self, topic: str, data: bytes, time_ns: int) -> None:
        """One already-encoded JSON message, its bytes written as they are."""
        self._sequence += 1
        self._writer.add_message(channel_id=self._channels[topic], log_time=time_ns,
                                 publish_time=time_ns, sequence=self._sequence, data=data)

    def log_metrics(self, iteration: int, metrics: dict[str, float], stage: str = "",
                    time_ns: int | None = None) -> None:
        """One /metrics message per iteration; flushed at once (the dashboard tails it)."""
        message = MetricsMessage(int(iteration), stage, dict(metrics))
        self.write(METRICS_TOPIC, message.to_json(), time_ns if time_ns is not None else time.time_ns())
        self._writer.flush()

    def log_scene(self, scene: SceneMessage) -> None:
        """/scene and its /foxglove/scene twin, at the wall-clock time."""
        from scene_builder.assets import default_assets_root

        now = time.time_ns()
        self._targets = list(scene.targets)
        self.write(SCENE_TOPIC, scene.to_json(), now)
        self.write(SCENE_UPDATE_TOPIC, scene_update(scene, self.assets_root or default_assets_root(), now), now)
        self._writer.flush()

    def frame_time_ns(self, frame: EpisodeFrame) -> int:
        """Where a frame sits on the timeline: its (episode, trial)'s origin + frame.time. An
        episode number's trials get consecutive slots after everything logged so far (a
        training recording, trial -1, the first)."""
        key = (int(frame.episode), int(frame.trial))
        origin = self._origins.get(key)
        if origin is None:
            base = self._episode_base.get(key[0])
            if base is None:
                base = max(time.time_ns(), self._timeline_end + 1_000_000_000)
                self._episode_base[key[0]] = base
            origin = self._origins[key] = base + int(max(key[1], 0) * self.episode_slot_s * 1e9)
        return origin + int(round(frame.time * 1e9))

    def log_frame(self, frame: EpisodeFrame) -> None:
        """One /episode/bodies frame plus its foxglove.FrameTransforms twin on /tf (bodies and
        dynamic objects) and its task markers on /foxglove/task."""
        time_ns = self.frame_time_ns(frame)
        self._timeline_end = max(self._timeline_end, time_ns)
        data = frame.to_json()
        self.write(EPISODE_TOPIC, data, time_ns)
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
        self._frames_since_flush += 1
        if self._frames_since_flush >= self.flush_every:
            self.flush()

    def flush(self) -> None:
        self._frames_since_flush = 0
        self._writer.flush()

    def close(self) -> None:
        """Write the summary section (indexes); the file is complete after this.

        A failure here (a full disk) is only reported: the summary is an index, every message
        already written stays readable without it, and the run's real error must not drown in
        a second traceback."""
        if self._file.closed:
            return
        try:
            self._writer.finish()
        except OSError as exc:
            with contextlib.suppress(OSError):
                print(f"note: {self.path.name} closed without its index ({exc.strerror or exc})", flush=True)
        finally:
            with contextlib.suppress(OSError):
                self._file.close()

    def __enter__(self) -> "RunLogWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def iter_raw_messages(path: Path, topics: Sequence[str] | None = None) -> Iterator[tuple[str, int, bytes]]:
    """(topic, log_time_ns, the message's JSON bytes) in file order; stops quietly at a
    truncated tail.

    Works on live files still being written and on files of crashed runs: everything up to
    the last complete chunk is returned.
    """
    wanted = set(topics) if topics is not None else None
    with open(path, "rb") as f:
        reader = NonSeekingReader(f)
        try:
            for _schema, channel, message in reader.iter_messages(log_time_order=False):
                if wanted is None or channel.topic in wanted:
                    yield channel.topic, message.log_time, message.data
        except Exception:  # noqa: BLE001 - a truncated or still-growing tail ends the read
            return


def iter_messages(path: Path, topics: Sequence[str] | None = None
                  ) -> Iterator[tuple[str, int, dict[str, Any]]]:
    """(topic, log_time_ns, message) in file order, decoded (`iter_raw_messages`); a message
    that is not JSON ends the read like a truncated tail."""
    for topic, time_ns, data in iter_raw_messages(path, topics):
        try:
            message = json.loads(data)
        except ValueError:
            return
        yield topic, time_ns, message


def _iteration(message: dict[str, Any]) -> int:
    value = message.get("iteration") if isinstance(message, dict) else None
    return value if isinstance(value, int) else -1


def read_metrics(path: Path) -> list[dict[str, Any]]:
    """Every /metrics message, in iteration order."""
    return [m for _t, _time, m in iter_messages(path, [METRICS_TOPIC])]


def read_scene(path: Path) -> SceneMessage | None:
    for _t, _time, m in iter_messages(path, [SCENE_TOPIC]):
        return SceneMessage.from_json(m)
    return None


def read_episodes(path: Path) -> dict[int, list[dict[str, Any]]]:
    """Frames of /episode/bodies grouped by episode number."""
    episodes: dict[int, list[dict[str, Any]]] = {}
    for _t, _time, m in iter_messages(path, [EPISODE_TOPIC]):
        episodes.setdefault(int(m["episode"]), []).append(m)
    return episodes
