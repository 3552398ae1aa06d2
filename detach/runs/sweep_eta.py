"""A sweep's time estimate, weighted by how much simulation each cell does.

The cells of one sweep differ severalfold in cost (the laptop preset's Follow cells train 400
iterations of 64 envs, its Carry cells 25 of 256: four times the samples, 49 against 10 minutes
for DETACH), so an ETA from the mean time per finished cell overstates the rest after a long
first cell (7.4 h said, 2.2 h taken). Here a
cell's work is the env steps it simulates (training samples plus its evaluations' trials at
full episode length), a finished cell gives seconds per step, and the cells still running
count with what they have left at that rate.
"""
from __future__ import annotations

import time
from typing import Callable, Hashable


class SweepClock:
    """Elapsed time and ETA of a sweep whose cells carry work weights (env steps)."""

    def __init__(self, jobs: int, now: Callable[[], float] = time.monotonic) -> None:
        self.jobs = max(jobs, 1)
        self.now = now
        self.started = now()
        self.weights: dict[Hashable, float | None] = {}
        """Cell still to run or running -> its work (None: not sized, counted as the mean)."""
        self.running: dict[Hashable, float] = {}
        """Cell -> when it started."""
        self.spent = 0.0
        """Seconds of finished cells, one slot each."""
        self.done_work = 0.0
        self._known: list[float] = []

    def add(self, cell: Hashable, work: float | None) -> None:
        """A cell still to run; `work` None when it could not be sized (counted as the mean)."""
        sized = work is not None and work > 0
        self.weights[cell] = float(work) if sized else None
        if sized:
            self._known.append(float(work))

    def start(self, cell: Hashable) -> None:
        self.running[cell] = self.now()

    def end(self, cell: Hashable) -> None:
        began = self.running.pop(cell, None)
        work = self._work(cell)
        self.weights.pop(cell, None)
        if began is not None:
            self.spent += self.now() - began
            self.done_work += work

    def skip(self, cell: Hashable) -> None:
        """A cell that will not run (its parent failed)."""
        self.weights.pop(cell, None)
        self.running.pop(cell, None)

    def eta_s(self) -> float | None:
        """Seconds left, or None before any cell has ended."""
        if self.done_work <= 0:
            return None
        rate = self.spent / self.done_work  # seconds per unit of work, one slot
        now = self.now()
        left = sum(max(self._work(c) - (now - self.running[c]) / rate, 0.0) if c in self.running
                   else self._work(c) for c in self.weights)
        slots = min(self.jobs, max(len(self.weights), 1))
        return rate * left / slots

    def progress(self) -> str:
        """'elapsed 12 min, ETA 1.5 h'."""
        eta = self.eta_s()
        return f"elapsed {duration(self.now() - self.started)}, ETA {'?' if eta is None else duration(eta)}"

    def _work(self, cell: Hashable) -> float:
        work = self.weights.get(cell)
        if work is not None:
            return work
        return sum(self._known) / len(self._known) if self._known else 1.0


def duration(seconds: float) -> str:
    if seconds >= 3600:
        return f"{seconds / 3600:.1f} h"
    return f"{seconds / 60:.0f} min" if seconds >= 60 else f"{seconds:.0f} s"
