"""A run folder: the only thing a run leaves behind and the only thing the dashboard reads.

runs/<YYYYmmdd-HHMMSS>-<task>-<model>-s<seed>/ holds config.yaml, status.json, stdout.log,
log.mcap, checkpoints/ and eval.json. Every JSON/YAML file is replaced atomically (write a
temporary file, then rename), so a reader never sees half a file.
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

RunState = Literal["queued", "running", "finished", "failed", "interrupted"]
STATES: tuple[str, ...] = ("queued", "running", "finished", "failed", "interrupted")


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
        return self.path / "config.yaml"

    @property
    def status_path(self) -> Path:
        return self.path / "status.json"

    @property
    def log_path(self) -> Path:
        return self.path / "log.mcap"

    @property
    def stdout_path(self) -> Path:
        return self.path / "stdout.log"

    @property
    def eval_path(self) -> Path:
        return self.path / "eval.json"

    @property
    def checkpoints(self) -> Path:
        return self.path / "checkpoints"

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

    def status(self) -> dict[str, Any]:
        return json.loads(self.status_path.read_text(encoding="utf-8"))

    def set_state(self, state: RunState, **fields: Any) -> dict[str, Any]:
        """Update status.json (state, pid, iteration, started, updated, error, ...)."""
        if state not in STATES:
            raise ValueError(f"unknown run state {state!r}")
        try:
            status = self.status()
        except (OSError, ValueError):
            status = {"started": None, "iteration": 0, "error": None}
        now = time.time()
        status.update(fields)
        status["state"] = state
        status["updated"] = now
        if state == "running" and not status.get("started"):
            status["started"] = now
        status.setdefault("pid", os.getpid())
        if state == "running":
            status["pid"] = os.getpid()
        atomic_write_json(self.status_path, status)
        return status

    def latest_checkpoint(self) -> Path | None:
        """Checkpoint with the highest iteration number (model_<iter>.pt)."""
        found = sorted(self.checkpoints.glob("model_*.pt"),
                       key=lambda p: int(p.stem.split("_")[-1]) if p.stem.split("_")[-1]
                       .isdigit() else -1)
        return found[-1] if found else None

    def eval_result(self) -> dict[str, Any] | None:
        if not self.eval_path.exists():
            return None
        return json.loads(self.eval_path.read_text(encoding="utf-8"))


def find_runs(parent: Path) -> list[RunFolder]:
    """Every folder under `parent` that looks like a run (has config.yaml or status.json)."""
    if not parent.is_dir():
        return []
    return [RunFolder(p) for p in sorted(parent.iterdir())
            if p.is_dir() and ((p / "config.yaml").exists() or (p / "status.json").exists())]
