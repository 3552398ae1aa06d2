"""Reading a whole log.mcap in file order (tools, tests, tables): up to a crash's cut.

The dashboard reads logs as they grow with `detach.runfolder.log_tail` instead, which reads
only what was appended since its last look.
"""

from __future__ import annotations

import json
from pathlib import Path
from typing import Any, Iterator, Sequence

from mcap.reader import NonSeekingReader

from detach.runfolder.messages import SceneMessage
from detach.runfolder.names import EPISODE_TOPIC, METRICS_TOPIC, SCENE_TOPIC


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
