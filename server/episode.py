"""One episode of /episode/bodies frames (`EpisodeFrame`) as arrays, built from its messages.

Kept apart from the log reader so that it can be tested and reused on plain message lists.
"""

from __future__ import annotations

from dataclasses import dataclass, field

import numpy as np

from detach import PathMemo, TaskState, task_state
from detach.runfolder.log_tail import EpisodeKey, LogTail
from detach.runfolder.messages import EpisodeFrame


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


def load_episode(log: LogTail, key: EpisodeKey | int | None = None) -> Episode | None:
    """The recorded episode `key` of a tailed log (`LogTail.episode_frames`; default: the
    newest) as arrays; None when the log holds no frame of it."""
    found = log.episode_frames(key)
    if found is None:
        return None
    (number, trial), frames = found
    return episode_from_frames(number, frames, trial=trial)


def episode_from_frames(number: int, frames: list[EpisodeFrame], trial: int = 0) -> Episode | None:
    """Stack one episode's /episode/bodies frames (file order) into arrays.

    A log can hold the same episode number more than once (each evaluation of a run
    records its episode 0 again): a frame number that does not increase starts a new
    recording, and only the last recording is kept.
    """
    start, last = 0, None
    for i, m in enumerate(frames):
        if last is not None and m.frame <= last:
            start = i
        last = m.frame
    by_frame = {m.frame: m for m in frames[start:]}
    ordered = [by_frame[k] for k in sorted(by_frame)]
    bodies = list(ordered[-1].bodies)
    good = [m for m in ordered if len(m.pos) == len(bodies) and len(m.quat) == len(bodies)]
    if not good or not bodies:
        return None
    pos = np.asarray([m.pos for m in good], dtype=np.float64).reshape(len(good), -1, 3)
    quat = np.asarray([m.quat for m in good], dtype=np.float64).reshape(len(good), -1, 4)
    times = np.asarray([float(m.time) for m in good])
    objects: dict[str, tuple[np.ndarray, np.ndarray]] = {}
    names = {o.get("name") for m in good for o in m.objects if o.get("name")}
    for name in sorted(names):
        p = np.full((len(good), 3), np.nan)
        q = np.full((len(good), 4), np.nan)
        for i, m in enumerate(good):
            for o in m.objects:
                if o.get("name") == name:
                    p[i] = o.get("pos", p[i])
                    q[i] = o.get("quat", (1.0, 0.0, 0.0, 0.0))
        objects[name] = (_fill_forward(p), _fill_forward(q))
    paths = PathMemo()
    fields = [{k: v for k, v in vars(m).items() if v is not None} for m in good]
    task = [task_state(f, pos[i, 0], paths.update(0, f)) for i, f in enumerate(fields)]
    return Episode(number, bodies, times, pos, quat, np.asarray([m.subtask for m in good]),
                   [m.skill for m in good], objects, trial, task)


def _fill_forward(a: np.ndarray) -> np.ndarray:
    """Carry the last known row over NaN rows (and the first known one backwards)."""
    ok = ~np.isnan(a).any(axis=1)
    if not ok.any():
        return np.zeros_like(a)
    idx = np.where(ok, np.arange(len(a)), 0)
    np.maximum.accumulate(idx, out=idx)
    idx[: np.argmax(ok)] = np.argmax(ok)
    return a[idx]
