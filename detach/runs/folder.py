"""A run folder on disk: creating it, its paths, its status, its checkpoints.

The format (file names, status.json, eval.json) is `detach.run_contract`. Every JSON/YAML
file is replaced atomically (`run_contract.atomic_writer`: a fsynced temporary file, then a
rename), so a reader never sees half a file, and files get the user's umask.

Whether a run is really alive is not what status.json says: a `kill -9` leaves `running`
behind. `owner_alive` asks the operating system when the recorded process is on this host
and trusts the heartbeat (`updated`, refreshed by `detach.runs.job` every
`HEARTBEAT_S`) when it is on another host sharing the runs folder.
"""

from __future__ import annotations

import contextlib
import errno
import json
import math
import os
import secrets
import socket
import threading
import time
from dataclasses import dataclass
from pathlib import Path
from typing import Any, Callable, Literal

from detach.config import ConfigError, dump, load_run_config
from detach.config_schema import RunConfig
from detach.runs import files as run_files
from detach.run_contract import (
    CHECKPOINT_DIR, CONFIG_FILE, EVAL_FILE, LIVE_STATES, LOG_FILE, RUN_MARKERS, RUN_STATES, SELECTION_FILE,
    REPLAY_PREFIX, STATUS_FILE, STDOUT_FILE, EvalResult, Status, atomic_writer, checkpoint_file, is_temp_file,
    replay_iteration,
)

RunState = Literal["queued", "running", "finished", "failed", "interrupted"]

HEARTBEAT_S = 30.0
"""How often a running job refreshes status.json's `updated` (detach.runs.job)."""
STALE_AFTER_S = 600.0
"""A run on another host whose status.json is older than this is taken for dead (generous:
clocks of machines sharing a folder may disagree by minutes)."""
MAX_JSON_BYTES = 16 * 1024 * 1024
"""status.json and eval*.json larger than this are refused unread (they are a few KB)."""

_STATUS_LOCK = threading.Lock()
"""status.json is read-modified-written by the job and its heartbeat thread."""
_NO_SPACE = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG)


def this_host() -> str:
    return socket.gethostname()


def atomic_write_text(path: Path, text: str) -> None:
    """Write `text` to `path` so that readers see the old or the new file, never a mix."""
    path.parent.mkdir(parents=True, exist_ok=True)
    with atomic_writer(path, binary=False) as f:
        f.write(text)


def atomic_write_json(path: Path, data: Any) -> None:
    atomic_write_text(path, json.dumps(data, indent=2, sort_keys=False) + "\n")


def read_json(path: Path) -> Any:
    """A small JSON file of the run folder (OSError if missing, ValueError if malformed, too
    large, nested too deeply, not a regular file or a link out of its folder:
    `detach.runs.files`)."""
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


def _process_start_time(pid: int) -> float | None:
    """Unix time at which process `pid` started (Linux /proc), None if unknown."""
    try:
        fields = Path(f"/proc/{pid}/stat").read_text().rsplit(")", 1)[1].split()
        boot = next(float(line.split()[1]) for line in Path("/proc/stat").read_text().splitlines()
                    if line.startswith("btime "))
        return boot + int(fields[19]) / os.sysconf("SC_CLK_TCK")
    except (OSError, ValueError, IndexError, StopIteration):
        return None


def pid_alive(pid: int, since: float | None = None) -> bool:
    """Whether process `pid` of this host exists (and, when `since` is given, started before
    that time, within clock resolution: a pid reused by a newer process is not the run's)."""
    if int(pid) <= 0:  # 0 and negative numbers name process groups, not a process
        return False
    try:
        os.kill(int(pid), 0)
    except ProcessLookupError:
        return False
    except PermissionError:
        pass  # another user's process: it exists
    except (OverflowError, ValueError):
        return False
    if since is not None:
        started = _process_start_time(int(pid))
        if started is not None and started > since + 2.0:
            return False
    return True


def owner_alive(status: Status, now: float | None = None) -> bool:
    """Whether the process that status.json names may still be working on the run.

    Finished, failed and interrupted runs have no owner. The current process is never
    counted (it is the one asking). A pid of another host is not looked up here: that
    machine's heartbeat (`updated`) decides."""
    if status.state not in LIVE_STATES or not status.pid:
        return False
    if status.host and status.host != this_host():
        return (now if now is not None else time.time()) - (status.updated or 0.0) < STALE_AFTER_S
    if status.pid == os.getpid():
        return False
    # The owner wrote `updated` after it started; a process younger than that reused the pid.
    return pid_alive(status.pid, since=status.updated)


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
            run.set_state("queued", iteration=0, run_id=secrets.token_hex(8))
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
        """Checkpoints (model_<iter>.pt), newest first."""
        from detach.train.checkpoints import checkpoint_files

        return checkpoint_files(self.path)

    def latest_checkpoint(self) -> Path | None:
        """Checkpoint with the highest iteration number (model_<iter>.pt)."""
        files = self.checkpoint_files()
        return files[0] if files else None

    def usable_checkpoint(self, map_location: str = "cpu", report: Callable[[str], None] = print) -> Path | None:
        """The newest checkpoint that reads back whole; training resumes from it
        (`detach.train.checkpoints.newest_readable_checkpoint`)."""
        from detach.train.checkpoints import newest_readable_checkpoint

        return newest_readable_checkpoint(self.path, map_location, report)

    def policy_checkpoint(self, map_location: str = "cpu", report: Callable[[str], None] = print) -> Path | None:
        """The run's policy: the checkpoint chosen on validation trials, else the newest that
        reads back whole (`detach.train.checkpoints.run_policy_checkpoint`). Training resumes
        from the newest (`usable_checkpoint`) whatever was selected."""
        from detach.train.checkpoints import run_policy_checkpoint

        return run_policy_checkpoint(self.path, map_location, report)

    def clear_selection(self) -> None:
        """Forget the chosen checkpoint (a resumed run trains on and chooses again)."""
        self.selection_path.unlink(missing_ok=True)

    def remove_stale_temp_files(self) -> list[Path]:
        """Delete temporary files that writers killed mid-write left behind (their pid, in the
        name, is dead) and AMP replay sidecars whose checkpoint was never written (a kill
        between the two files); returns what was removed. Call when taking ownership of the run."""
        removed = []
        if self.checkpoints.is_dir():
            for path in self.checkpoints.glob(f"{REPLAY_PREFIX}*.pt"):
                iteration = replay_iteration(path.name)
                if iteration is not None and not (self.checkpoints / checkpoint_file(iteration)).exists():
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


def implausible(result: EvalResult) -> str | None:
    """Why numbers that follow the contract are still impossible (None when they are fine):
    no trials, or a statistic that is not a finite number."""
    if result.trials < 1:
        return f"'trials' must be >= 1, found {result.trials}"
    sgr = result.sgr.values() if isinstance(result.sgr, dict) else [result.sgr]
    numbers = {"sgr": list(sgr), "mean_execution_time": [result.mean_execution_time],
               "execution_time_ci": list(result.execution_time_ci or [])}
    for key, values in numbers.items():
        if any(v is not None and not (isinstance(v, (int, float)) and math.isfinite(v)) for v in values):
            return f"'{key}' is not a finite number"
    return None


def read_eval(path: Path) -> EvalResult:
    """One eval*.json, checked (OSError, or ValueError naming the file and what is wrong)."""
    result = EvalResult.from_json(read_json(path), str(path))
    problem = implausible(result)
    if problem is not None:
        raise ValueError(f"{path}: {problem}")
    return result


def find_runs(parent: Path) -> list[RunFolder]:
    """Every folder under `parent` that looks like a run (has config.yaml or status.json)."""
    if not parent.is_dir():
        return []
    return [RunFolder(p) for p in sorted(parent.iterdir())
            if p.is_dir() and any((p / m).exists() for m in RUN_MARKERS)]
