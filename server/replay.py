"""Replay of an episode: a clock over its frame times and the thread that draws frames.

The clock is pure (tests drive it with explicit time steps); the thread ticks at 30 Hz and
draws only when the frame index changed, so a paused replay costs nothing.
"""

from __future__ import annotations

import threading
import time
from typing import Callable

import numpy as np

from server.episode import Episode

FPS = 30.0


class Player:
    """Play/pause, speed and seek over frame times (seconds). Loops at the end, or holds
    there when following a live run so that new frames play as they arrive."""

    def __init__(self) -> None:
        self.times = np.zeros(1)
        self.t = 0.0
        self.speed = 1.0
        self.playing = True
        self.hold_at_end = False

    def load(self, times: np.ndarray, keep_time: bool = False) -> None:
        self.times = np.asarray(times, dtype=float) if len(times) else np.zeros(1)
        if not keep_time:
            self.t = float(self.times[0])
        self.t = float(np.clip(self.t, self.times[0], self.times[-1]))

    @property
    def frame(self) -> int:
        return int(np.clip(np.searchsorted(self.times, self.t + 1e-9, "right") - 1, 0,
                           len(self.times) - 1))

    def advance(self, dt: float) -> int:
        """Move the clock by `dt` wall seconds (times speed); returns the frame to show."""
        if self.playing:
            self.t += dt * self.speed
            start, end = float(self.times[0]), float(self.times[-1])
            if self.t > end:
                if self.hold_at_end or end <= start:
                    self.t = end
                else:  # loop, keeping the overshoot so the pace stays even
                    self.t = start + (self.t - end) % max(end - start + 1.0 / FPS, 1e-6)
        return self.frame

    def seek(self, frame: int) -> None:
        self.t = float(self.times[int(np.clip(frame, 0, len(self.times) - 1))])


class ReplayThread:
    """Calls `draw(episode, frame)` whenever the shown frame changes (at most FPS times/s)."""

    def __init__(self, draw: Callable[[Episode, int], None]) -> None:
        self.player = Player()
        self.episode: Episode | None = None
        self.shown = -1
        self.lock = threading.RLock()
        self._draw = draw
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="replay", daemon=True)
        self.frame_cost = 0.0
        """Seconds spent in the last `draw` (the per-frame server cost)."""

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def set_episode(self, episode: Episode | None, keep_time: bool = False) -> None:
        with self.lock:
            self.episode = episode
            if episode is not None:
                self.player.load(episode.times, keep_time)
            self.shown = -1
            self.redraw()

    def redraw(self) -> None:
        """Draw the current frame now (after a seek, or while paused)."""
        with self.lock:
            if self.episode is not None:
                self._show(self.player.frame)

    def _show(self, frame: int) -> None:
        t0 = time.perf_counter()
        self._draw(self.episode, frame)
        self.frame_cost = time.perf_counter() - t0
        self.shown = frame

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            dt, last = now - last, now
            with self.lock:
                if self.episode is not None and self.player.playing:
                    frame = self.player.advance(dt)
                    if frame != self.shown:
                        try:
                            self._show(frame)
                        except Exception as exc:  # noqa: BLE001 - keep replaying
                            print(f"detach-dashboard: replay frame failed: {exc!r}")
                            self.player.playing = False
            self._stop.wait(max(0.0, 1.0 / FPS - (time.monotonic() - now)))
