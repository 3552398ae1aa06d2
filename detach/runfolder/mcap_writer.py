"""Writing a run's log.mcap: the package's JSON messages on their topics, readable up to a crash.

Topics and message types: /metrics `MetricsMessage`, /scene `SceneMessage`, /episode/bodies
`EpisodeFrame` (`detach.runfolder.messages`). A writer may register more channels
(`extra_channels`: the Foxglove twins of `detach.runs.mcap_log.RunLogWriter`) and write their
messages from the `after_scene` / `after_frame` hooks. Chunks are flushed after every metrics
message and every `flush_every` frames, so a crashed run's log reads up to its last flush.

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
from typing import Any, BinaryIO, Sequence

from mcap.writer import CompressionType, Writer

from detach.runfolder.mcap_reader import iter_raw_messages
from detach.runfolder.messages import MCAP_SCHEMAS, EpisodeFrame, MetricsMessage, SceneMessage
from detach.runfolder.names import EPISODE_TOPIC, METRICS_TOPIC, SCENE_TOPIC, TEMP_SUFFIX

Channel = tuple[str, str, dict[str, Any]]
"""(topic, schema name, JSON schema) of a channel a writer registers besides the package's."""


class McapLogWriter:
    """Append-only writer of a run's log.mcap (one writer per process)."""

    episode_slot_s = 60.0
    """Timeline room per recorded trial (episodes are capped at 40 s in the shipped tasks)."""

    def __init__(self, path: Path, flush_every: int = 30, append: bool = False,
                 metrics_until: int | None = None, extra_channels: Sequence[Channel] = ()) -> None:
        """`append=True` keeps the messages of an existing log (a resumed run): MCAP files
        cannot be appended to, so they are copied into a fresh file that replaces it.
        `metrics_until` (the resumed checkpoint's iteration) drops the /metrics messages of
        later iterations: the run trains them again, and a log must hold each iteration once."""
        self.path = Path(path)
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
        for topic, name, schema in extra_channels:
            self._channels[topic] = self._register(topic, name, schema)
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
        """/scene (and what `after_scene` adds), at the wall-clock time."""
        now = time.time_ns()
        self.write(SCENE_TOPIC, scene.to_json(), now)
        self.after_scene(scene, now)
        self._writer.flush()

    def after_scene(self, scene: SceneMessage, time_ns: int) -> None:
        """Messages a subclass writes with each scene (none here)."""

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
        """One /episode/bodies frame (and what `after_frame` adds)."""
        time_ns = self.frame_time_ns(frame)
        self._timeline_end = max(self._timeline_end, time_ns)
        data = frame.to_json()
        self.write(EPISODE_TOPIC, data, time_ns)
        self.after_frame(frame, data, time_ns)
        self._frames_since_flush += 1
        if self._frames_since_flush >= self.flush_every:
            self.flush()

    def after_frame(self, frame: EpisodeFrame, data: dict[str, Any], time_ns: int) -> None:
        """Messages a subclass writes with each frame (`data`: the frame as written)."""

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

    def __enter__(self) -> "McapLogWriter":
        return self

    def __exit__(self, *exc: object) -> None:
        self.close()


def _iteration(message: dict[str, Any]) -> int:
    value = message.get("iteration") if isinstance(message, dict) else None
    return value if isinstance(value, int) else -1
