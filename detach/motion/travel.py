"""How far and how fast a clip's root travels: path length, not net displacement.

A real 0.83 m/s walk that goes forward and back ends where it started; its net displacement
(0.01 m) says nothing about its speed. The path length is summed over the root's horizontal
positions sampled every `SAMPLE_S` seconds (and the last frame): frame-to-frame sums at 120 fps
would add mocap jitter (~0.5 mm per frame, ~0.06 m/s) to the speed, while 0.1 s is well below a
step (~0.5 s), so turns and back-and-forth walking are kept. Metres, seconds, world frame.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

SAMPLE_S = 0.1
"""Seconds between the root positions the path length is summed over."""


@dataclass(frozen=True)
class RootTravel:
    path_length: float
    """Metres travelled by the root in the horizontal plane."""
    net_displacement: float
    """Metres between the first and last horizontal root positions."""
    path_speed: float
    """path_length / duration, m/s (0 for a single frame)."""


def root_travel(root_pos: np.ndarray, fps: float) -> RootTravel:
    """Travel of root positions [F, 3] (metres) sampled at `fps` frames per second."""
    xy = np.asarray(root_pos, dtype=np.float64)[:, :2]
    frames = len(xy)
    duration = (frames - 1) / fps if frames > 1 else 0.0
    step = max(int(round(SAMPLE_S * fps)), 1)
    idx = np.unique(np.append(np.arange(0, frames, step), frames - 1))
    path = float(np.linalg.norm(np.diff(xy[idx], axis=0), axis=1).sum()) if frames > 1 else 0.0
    net = float(np.linalg.norm(xy[-1] - xy[0])) if frames else 0.0
    return RootTravel(path, net, path / duration if duration > 0 else 0.0)
