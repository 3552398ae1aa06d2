"""A run folder on disk: creating it, its paths, its status, its evaluations.

The format is this package's (`names`, `messages`, `eval_result`); every JSON/YAML file is
replaced atomically (`atomic`), and every file is read through `files` (regular files of the
folder, within a size cap). Whether the run's owner is alive: `liveness`.
"""

from __future__ import annotations

import contextlib
import errno
import json
import os
import secrets
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Literal

from detach.config import ConfigError, dump, load_run_config
from detach.config.schema import RunConfig
from detach.runfolder import files as run_files
from detach.runfolder.atomic import atomic_write_text
from detach.runfolder.checkpoints import checkpoint_files, replays_in
from detach.runfolder.eval_result import EvalResult, implausible
from detach.runfolder.liveness import owner_alive, pid_alive, this_host
from detach.runfolder.messages import RunSummary, Status
from detach.runfolder.names import (
    AGENT_PARAMS_FILE, CHECKPOINT_DIR, CONFIG_FILE, EVAL_FILE, EVAL_GLOB, EXPORT_DIR, LOG_FILE, PROVENANCE_FILE,
    RUN_MARKERS, RUN_STATES, SELECTION_FILE, STATUS_FILE, STDOUT_FILE, checkpoint_file, eval_file, is_eval_file,
    is_temp_file,
)
from detach.runfolder.summary import read_config_summary, summary_of_config

RunState = Literal["queued", "running", "finished", "failed", "interrupted"]

MAX_JSON_BYTES = 16 * 1024 * 1024
"""status.json and eval*.json larger than this are refused unread (they are a few KB)."""

_STATUS_LOCK = threading.Lock()
"""status.json is read-modified-written by the job and its heartbeat thread."""
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def read_json(path: Path) -> Any:
    """A small JSON file of the run folder (OSError if missing, ValueError if malformed, too
    large, nested too deeply, not a regular file or a link out of its folder:
    `detach.runfolder.files`)."""
    return run_files.read_json(path.parent, path.name, MAX_JSON_BYTES)


def _overwrite_in_place(path: Path, text: str) -> None:
    """Last resort on a full disk: rewrite a small existing file in the blocks it already owns
    (a rename needs a new file, which needs space). Readers may glimpse a partial file."""
    with open(path, "r+b") as f:
        f.write(text.encode("utf-8"))
        f.truncate()
        f.flush()
        os.fsync(f.fileno())


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
    def selection_path(self) -> Path:
        return self.path / SELECTION_FILE

    @property
    def checkpoints(self) -> Path:
        return self.path / CHECKPOINT_DIR

    @property
    def provenance_path(self) -> Path:
        return self.path / PROVENANCE_FILE

    @property
    def agent_params_path(self) -> Path:
        """rsl-rl's train config of the run (params/agent.yaml)."""
        return self.path / AGENT_PARAMS_FILE

    @property
    def export_dir(self) -> Path:
        return self.path / EXPORT_DIR

    def evaluation_path(self, task: str | None = None, trial_set: str | None = None) -> Path:
        """Where the evaluation on `task` (None: the run's own) and `trial_set` goes (`eval_file`)."""
        return self.path / eval_file(task, trial_set)

    def evaluation_paths(self) -> list[Path]:
        """Every eval*.json of the run, sorted by name."""
        return sorted(self.path.glob(EVAL_GLOB))

    def evaluation_names(self) -> list[str]:
        """The names of the run's eval*.json files, sorted (OSError if the folder is unreadable)."""
        return sorted(n for n in os.listdir(self.path) if is_eval_file(n))

    @classmethod
    def create(cls, parent: Path, cfg: RunConfig, now: float | None = None) -> "RunFolder":
        """Make a new folder (a numeric suffix if the name is taken) in state `queued`.

        All or nothing: if any file cannot be written (read-only or full disk), the folder is
        removed again and the OSError raised."""
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
        try:
            run.checkpoints.mkdir()
            atomic_write_text(run.config_path, dump(cfg))
            run.set_state("queued", iteration=0, run_id=secrets.token_hex(8), summary=summary_of_config(cfg))
        except BaseException:
            run._remove_new_folder()
            raise
        return run

    def _remove_new_folder(self) -> None:
        for child in (self.checkpoints, self.config_path, self.status_path):
            with contextlib.suppress(OSError):
                child.rmdir() if child.is_dir() else child.unlink()
        with contextlib.suppress(OSError):
            self.path.rmdir()

    def config(self) -> RunConfig:
        """config.yaml, read only if it is a regular file of this folder within its cap
        (ConfigError, one line, otherwise: a link to /etc/passwd must not be echoed)."""
        try:
            run_files.check_run_file(self.path, CONFIG_FILE)
        except run_files.RunFileError as exc:
            raise ConfigError(str(exc)) from None
        except OSError:
            pass  # missing or unreadable: the loader says so
        return load_run_config(self.config_path)

    def status(self) -> Status:
        """status.json (OSError if missing, ValueError if malformed)."""
        return Status.from_json(read_json(self.status_path))

    def summary(self) -> RunSummary:
        """Task, model, seed and samples per iteration: status.json's summary, else (a folder of
        an earlier version) config.yaml's (`detach.runfolder.summary`). config.yaml is read
        either way, as the dashboard's index reads it: a run folder whose config.yaml is
        missing, refused or malformed is not summarised (OSError or ValueError for status.json,
        ConfigError, one line, for config.yaml)."""
        status = self.status()
        try:
            from_config = read_config_summary(self.path)
        except FileNotFoundError:
            raise ConfigError("file not found", str(self.config_path)) from None
        except ValueError as exc:  # refused (a link out, too large, an alias bomb) or malformed
            raise ConfigError(str(exc) if isinstance(exc, run_files.RunFileError) else
                              f"{self.config_path}: {exc}") from None
        return status.summary or from_config

    def run_id(self) -> str:
        """The run's id from status.json, which a copy of the folder shares; the folder name for
        a folder of an earlier version (or an unreadable status.json)."""
        try:
            return self.status().run_id or self.path.name
        except (OSError, ValueError):
            return self.path.name

    def set_state(self, state: RunState, **fields: Any) -> Status:
        """Update status.json (state, pid, host, iteration, started, updated, error, cell)."""
        if state not in RUN_STATES:
            raise ValueError(f"unknown run state {state!r}")
        with _STATUS_LOCK:
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
                status.pid, status.host = os.getpid(), this_host()
            self._write_status(status)
        return status

    def heartbeat(self) -> None:
        """Refresh `updated` of a run this process is running (other hosts read it)."""
        with _STATUS_LOCK:
            try:
                status = self.status()
            except (OSError, ValueError):
                return
            if status.state != "running" or status.pid != os.getpid():
                return
            status.updated = time.time()
            with contextlib.suppress(OSError):
                self._write_status(status)

    def _write_status(self, status: Status) -> None:
        text = json.dumps(status.to_json(), indent=2) + "\n"
        try:
            atomic_write_text(self.status_path, text)
        except OSError as exc:
            if exc.errno not in _NO_SPACE or not self.status_path.exists():
                raise
            _overwrite_in_place(self.status_path, text)

    def owner_alive(self) -> bool:
        """Whether another live process owns this run (see `owner_alive`)."""
        try:
            return owner_alive(self.status())
        except (OSError, ValueError):
            return False

    def checkpoint_files(self) -> list[Path]:
        """Checkpoints (model_<iter>.pt), newest first (the run's policy and the checkpoint to
        resume from need torch to read: `detach.train.checkpoints`)."""
        return checkpoint_files(self.path)

    def latest_checkpoint(self) -> Path | None:
        """Checkpoint with the highest iteration number (model_<iter>.pt)."""
        files = self.checkpoint_files()
        return files[0] if files else None

    def clear_selection(self) -> None:
        """Forget the chosen checkpoint (a resumed run trains on and chooses again)."""
        self.selection_path.unlink(missing_ok=True)

    def remove_stale_temp_files(self) -> list[Path]:
        """Delete temporary files that writers killed mid-write left behind (their pid, in the
        name, is dead) and AMP replay sidecars whose checkpoint was never written (a kill
        between the two files); returns what was removed. Call when taking ownership of the run."""
        removed = []
        if self.checkpoints.is_dir():
            for iteration, path in replays_in(self.checkpoints).items():
                if not (self.checkpoints / checkpoint_file(iteration)).exists():
                    with contextlib.suppress(OSError):
                        path.unlink()
                        removed.append(path)
        for folder in (self.path, self.checkpoints):
            if not folder.is_dir():
                continue
            for path in folder.iterdir():
                legacy = path.name.endswith(".pt.tmp") or path.name == f".{LOG_FILE}.tmp"
                if not (legacy or is_temp_file(path.name)):
                    continue
                parts = path.name.rsplit(".", 3)
                pid = int(parts[1]) if len(parts) == 4 and parts[1].isdigit() else None
                if pid is not None and (pid == os.getpid() or pid_alive(pid)):
                    continue
                with contextlib.suppress(OSError):
                    path.unlink()
                    removed.append(path)
        return removed

    def eval_result(self) -> EvalResult | None:
        """eval.json (None if missing; ValueError if malformed or impossible)."""
        if not self.eval_path.exists():
            return None
        return read_eval(self.eval_path)


def read_eval(path: Path) -> EvalResult:
    """One eval*.json, checked (OSError, or ValueError naming the file and what is wrong)."""
    result = EvalResult.from_json(read_json(path), str(path))
    problem = implausible(result)
    if problem is not None:
        raise ValueError(f"{path}: {problem}")
    return result


def is_run_folder(path: Path) -> bool:
    """Whether `path` looks like a run folder (has config.yaml or status.json)."""
    return any(os.path.exists(Path(path) / m) for m in RUN_MARKERS)


def find_runs(parent: Path) -> list[RunFolder]:
    """Every folder under `parent` that looks like a run (has config.yaml or status.json)."""
    if not parent.is_dir():
        return []
    return [RunFolder(p) for p in sorted(parent.iterdir()) if p.is_dir() and is_run_folder(p)]
