"""One episode of /episode/bodies frames as arrays, built from its messages.

Kept apart from the log reader so that it can be tested and reused on plain message lists.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any

import numpy as np

from detach.eval.task_markers import PathMemo, TaskState, task_state


@dataclass
class Episode:
    """One episode's frames as arrays (positions in metres, world frame; quaternions wxyz)."""

    number: int
    bodies: list[str]
    times: np.ndarray
    """[F] seconds."""
    pos: np.ndarray
    """[F, B, 3]."""
    quat: np.ndarray
    """[F, B, 4] (w, x, y, z), MuJoCo order."""
    subtask: np.ndarray
    """[F] index of the current subtask."""
    skill: list[str]
    objects: dict[str, tuple[np.ndarray, np.ndarray]] = field(default_factory=dict)
    """Dynamic object name -> ([F, 3] positions, [F, 4] wxyz), carried forward over gaps."""
    trial: int = 0
    """Which trial of the episode number (an evaluation records all of its trials)."""
    task: list[TaskState] = field(default_factory=list)
    """Per frame, what its task markers are drawn from (target, Follow path, verdict)."""

    @property
    def num_frames(self) -> int:
        return len(self.times)


def episode_from_frames(number: int, frames: list[dict[str, Any]], trial: int = 0
                        ) -> Episode | None:
    """Stack one episode's /episode/bodies messages (file order) into arrays.

    A log can hold the same episode number more than once (each evaluation of a run
    records its episode 0 again): a frame number that does not increase starts a new
    recording, and only the last recording is kept.
    """
    start, last = 0, None
    for i, m in enumerate(frames):
        f = m.get("frame", i)
        if last is not None and isinstance(f, int) and f <= last:
            start = i
        last = f if isinstance(f, int) else last
    by_frame: dict[int, dict[str, Any]] = {}
    for i, m in enumerate(frames[start:]):
        by_frame[int(m.get("frame", i))] = m
    ordered = [by_frame[k] for k in sorted(by_frame)]
    bodies = list(ordered[-1].get("bodies", []))
    good = [m for m in ordered if len(m.get("pos", ())) == len(bodies)
            and len(m.get("quat", ())) == len(bodies)]
    if not good or not bodies:
        return None
    pos = np.asarray([m["pos"] for m in good], dtype=np.float64).reshape(len(good), -1, 3)
    quat = np.asarray([m["quat"] for m in good], dtype=np.float64).reshape(len(good), -1, 4)
    times = np.asarray([float(m.get("time", i / 30.0)) for i, m in enumerate(good)])
    objects: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    names = {o.get("name") for m in good for o in m.get("objects", ()) if o.get("name")}
    for name in sorted(names):
        p = np.full((len(good), 3), np.nan)
        q = np.full((len(good), 4), np.nan)
        for i, m in enumerate(good):
            for o in m.get("objects", ()):
                if o.get("name") == name:
                    p[i] = o.get("pos", p[i])
                    q[i] = o.get("quat", (1.0, 0.0, 0.0, 0.0))
        objects[name] = (_fill_forward(p), _fill_forward(q))
    paths = PathMemo()
    task = [task_state(m, pos[i, 0], paths.update(0, m)) for i, m in enumerate(good)]
    return Episode(number, bodies, times, pos, quat,
                   np.asarray([int(m.get("subtask", 0)) for m in good]),
                   [str(m.get("skill", "")) for m in good], objects, trial, task)


def _fill_forward(a: np.ndarray) -> np.ndarray:
    """Carry the last known row over NaN rows (and the first known one backwards)."""
    ok = ~np.isnan(a).any(axis=1)
    if not ok.any():
        return np.zeros_like(a)
    idx = np.where(ok, np.arange(len(a)), 0)
    np.maximum.accumulate(idx, out=idx)
    idx[: np.argmax(ok)] = np.argmax(ok)
    return a[idx]
