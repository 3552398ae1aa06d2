"""A LogWriter that drops everything: for runs whose metrics go elsewhere (or tests)."""

from __future__ import annotations

from rsl_rl.utils.log_writer import LogWriter


class NullWriter(LogWriter):
    def __init__(self, log_dir: str | None = None, **_: object) -> None:
        self.log_dir = log_dir

    def add_scalar(self, tag: str, scalar_value: float, global_step: int) -> None:
        """Metrics are written by the runner's own MCAP log instead."""
