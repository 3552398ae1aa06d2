"""Replay of episodes: a clock over frame times, one per browser, and the thread that ticks them.

The clock is pure (tests drive it with explicit time steps). Each browser has a `Replay`: its
clock and the episodes it shows (slot 'a', and 'b' for a run compared side by side, both on
the same clock). One `Ticker` thread advances every browser's replay at 30 Hz and draws only
when a shown frame changed, so a paused replay costs nothing.
"""

from __future__ import annotations

import threading
import time
import weakref
from typing import Callable

import numpy as np

from server.episode import Episode

FPS = 30.0


class Player:
    """Play/pause, speed, loop and seek over frame times (seconds). At the end it loops, or
    stops (loop off), or holds there when following a live run so that new frames play as
    they arrive."""

    def __init__(self) -> None:
        self.times = np.zeros(1)
        self.t = 0.0
        self.speed = 1.0
        self.playing = True
        self.loop = True
        self.hold_at_end = False

    def load(self, times: np.ndarray, keep_time: bool = False) -> None:
        self.times = np.asarray(times, dtype=float) if len(times) else np.zeros(1)
        if not keep_time:
            self.t = float(self.times[0])
        self.t = float(np.clip(self.t, self.times[0], self.times[-1]))

    @property
    def frame(self) -> int:
        return frame_at(self.times, self.t)

    @property
    def num_frames(self) -> int:
        return len(self.times)

    def advance(self, dt: float) -> int:
        """Move the clock by `dt` wall seconds (times speed); returns the frame to show."""
        if self.playing:
            self.t += dt * self.speed
            start, end = float(self.times[0]), float(self.times[-1])
            if self.t > end:
                if self.hold_at_end or end <= start:
                    self.t = end
                elif not self.loop:
                    self.t, self.playing = end, False
                else:  # loop, keeping the overshoot so the pace stays even
                    self.t = start + (self.t - end) % max(end - start + 1.0 / FPS, 1e-6)
        return self.frame

    def seek(self, frame: int) -> None:
        self.t = float(self.times[int(np.clip(frame, 0, len(self.times) - 1))])

    def step(self, frames: int) -> int:
        """Pause and move by whole frames (the step buttons); returns the new frame."""
        self.playing = False
        self.seek(self.frame + frames)
        return self.frame


def frame_at(times: np.ndarray, t: float) -> int:
    """Index of the frame shown at time `t` (the last frame that started at or before it)."""
    return int(np.clip(np.searchsorted(times, t + 1e-9, "right") - 1, 0, len(times) - 1))


class Replay:
    """One browser's replay: episodes per slot on one clock, drawn by `draw(slot, ep, i)`;
    `on_frame(episode, i)` follows slot 'a' (the controls show its time and subtask)."""

    def __init__(self, draw: Callable[[str, Episode, int], None],
                 on_frame: Callable[[Episode, int], None] | None = None) -> None:
        self.player = Player()
        self.episodes: dict[str, Episode] = {}
        self.shown: dict[str, int] = {}
        self.lock = threading.RLock()
        self._draw = draw
        self.on_frame = on_frame or (lambda ep, i: None)
        self.frame_cost = 0.0
        """Seconds spent drawing the last frame (the per-frame server cost)."""

    @property
    def episode(self) -> Episode | None:
        """The episode of slot 'a' (the run the replay tab is about)."""
        return self.episodes.get("a")

    def _clock_episode(self) -> Episode | None:
        return self.episodes.get("a") or self.episodes.get("b")

    def set_episode(self, slot: str, episode: Episode | None, keep_time: bool = False) -> None:
        with self.lock:
            if episode is None:
                self.episodes.pop(slot, None)
            else:
                self.episodes[slot] = episode
            self.shown.pop(slot, None)
            clock = self._clock_episode()
            if clock is not None and (slot == "a" or "a" not in self.episodes):
                self.player.load(clock.times, keep_time)
            self.redraw()

    def redraw(self) -> None:
        """Draw the current frame now (after a seek, a step, or while paused)."""
        with self.lock:
            self.shown.clear()
            self._show()

    def _show(self) -> None:
        t0 = time.perf_counter()
        for slot, ep in list(self.episodes.items()):
            i = frame_at(ep.times, self.player.t)
            if self.shown.get(slot) != i:
                self._draw(slot, ep, i)
                self.shown[slot] = i
                if slot == "a":
                    self.on_frame(ep, i)
        self.frame_cost = time.perf_counter() - t0

    def tick(self, dt: float) -> None:
        with self.lock:
            if self.episodes and self.player.playing:
                self.player.advance(dt)
                self._show()


class Ticker:
    """The one thread that advances every browser's replay at `FPS`."""

    def __init__(self) -> None:
        self._replays: weakref.WeakSet[Replay] = weakref.WeakSet()
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._run, name="replay", daemon=True)

    def add(self, replay: Replay) -> None:
        self._replays.add(replay)

    def discard(self, replay: Replay) -> None:
        self._replays.discard(replay)

    def start(self) -> None:
        self._thread.start()

    def stop(self) -> None:
        self._stop.set()

    def _run(self) -> None:
        last = time.monotonic()
        while not self._stop.is_set():
            now = time.monotonic()
            dt, last = now - last, now
            for replay in list(self._replays):
                try:
                    replay.tick(dt)
                except Exception as exc:  # noqa: BLE001 - one browser's bad frame stops only it
                    print(f"detach-dashboard: replay frame failed: {exc!r}", flush=True)
                    replay.player.playing = False
            self._stop.wait(max(0.0, 1.0 / FPS - (time.monotonic() - now)))
