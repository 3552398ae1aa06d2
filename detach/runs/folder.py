"""A run folder on disk: creating it, its paths, its status, its checkpoints.

The format (file names, status.json, eval.json) is `detach.run_contract`. Every JSON/YAML
file is replaced atomically (write a temporary file, then rename), so a reader never sees
half a file.
"""

from __future__ import annotations

import json
import os
import tempfile
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from detach.config import dump, load_run_config
from detach.config_schema import RunConfig
from detach.run_contract import (
    CHECKPOINT_DIR, CONFIG_FILE, EVAL_FILE, LOG_FILE, RUN_MARKERS, RUN_STATES, STATUS_FILE, STDOUT_FILE,
    EvalResult, Status, checkpoint_iteration,
)

RunState = Literal["queued", "running", "finished", "failed", "interrupted"]


def atomic_write_text(path: Path, text: str) -> None:
    """Write `text` to `path` so that readers see the old or the new file, never a mix."""
    path.parent.mkdir(parents=True, exist_ok=True)
    fd, tmp = tempfile.mkstemp(prefix=f".{path.name}.", dir=path.parent)
    try:
        with os.fdopen(fd, "w", encoding="utf-8") as f:
            f.write(text)
        os.replace(tmp, path)
    except BaseException:
        Path(tmp).unlink(missing_ok=True)
        raise


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def run_folder_name(cfg: RunConfig, now: float | None = None) -> str:
    """<YYYYmmdd-HHMMSS>-<task>-<model>-s<seed> (the run folder contract)."""
    stamp = time.strftime("%Y%m%d-%H%M%S", time.localtime(now))
    return f"{stamp}-{cfg.task_name}-{cfg.model_name}-s{cfg.seed}"


@dataclass
class RunFolder:
    """Paths and state of one run folder."""

    path: Path

    @property
    def config_path(self) -> Path:
        return self.path / CONFIG_FILE

    @property
    def status_path(self) -> Path:
        return self.path / STATUS_FILE

    @property
    def log_path(self) -> Path:
        return self.path / LOG_FILE

    @property
    def stdout_path(self) -> Path:
        return self.path / STDOUT_FILE

    @property
    def eval_path(self) -> Path:
        return self.path / EVAL_FILE

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINT_DIR

    @classmethod
    def create(cls, parent: Path, cfg: RunConfig, now: float | None = None) -> "RunFolder":
        """Make a new folder (a numeric suffix if the name is taken) in state `queued`."""
        parent.mkdir(parents=True, exist_ok=True)
        base = run_folder_name(cfg, now)
        path, k = parent / base, 1
        while True:
            try:
                path.mkdir()
                break
            except FileExistsError:
                k += 1
                path = parent / f"{base}-{k}"
        run = cls(path)
        run.checkpoints.mkdir()
        atomic_write_text(run.config_path, dump(cfg))
        run.set_state("queued", iteration=0)
        return run

    def config(self) -> RunConfig:
        return load_run_config(self.config_path)

    def status(self) -> Status:
        """status.json (OSError if missing, ValueError if malformed)."""
        return Status.from_json(json.loads(self.status_path.read_text(encoding="utf-8")))

    def set_state(self, state: RunState, **fields: Any) -> Status:
        """Update status.json (state, pid, iteration, started, updated, error, cell)."""
        if state not in RUN_STATES:
            raise ValueError(f"unknown run state {state!r}")
        try:
            status = self.status()
        except (OSError, ValueError):
            status = Status(state)
        now = time.time()
        for key, value in fields.items():
            setattr(status, key, value)
        status.state, status.updated = state, now
        if state == "running" and not status.started:
            status.started = now
        if state == "running" or status.pid is None:
            status.pid = os.getpid()
        atomic_write_json(self.status_path, status.to_json())
        return status

    def latest_checkpoint(self) -> Path | None:
        """Checkpoint with the highest iteration number (model_<iter>.pt)."""
        found = [(checkpoint_iteration(p.name), p) for p in self.checkpoints.glob("*.pt")]
        found = sorted((it, p) for it, p in found if it is not None)
        return found[-1][1] if found else None

    def eval_result(self) -> EvalResult | None:
        """eval.json (None if missing; ValueError if malformed)."""
        if not self.eval_path.exists():
            return None
        return EvalResult.from_json(json.loads(self.eval_path.read_text(encoding="utf-8")), str(self.eval_path))


def find_runs(parent: Path) -> list[RunFolder]:
    """Every folder under `parent` that looks like a run (has config.yaml or status.json)."""
    if not parent.is_dir():
        return []
    return [RunFolder(p) for p in sorted(parent.iterdir())
            if p.is_dir() and any((p / m).exists() for m in RUN_MARKERS)]
