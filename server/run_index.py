"""The runs/ folder as the dashboard sees it: one cached reader per run folder.

Each refresh stats the small files of a run and re-parses only those whose (size, mtime)
changed. log.mcap is not read at all until a browser opens the run (curves, replay): the
index only stats it, and checks a finished run's log from its first and last bytes (a full
scan runs only to say why a log is broken). Opened logs are tailed incrementally
(`detach.runfolder.log_tail`) and dropped again when nobody shows them, so memory follows what is on
screen, not the size of runs/.

With `settled_per_refresh`, runs that can no longer change by themselves (finished, failed,
interrupted) are re-checked a few per refresh, round-robin, while new and live runs are
checked on every refresh: a poll costs the same with 200 runs as with 20, and a finished run
that changes (an `--eval` appends to it, a `--resume` restarts it) shows within
len(runs) / settled_per_refresh polls.

Whatever is wrong with a run (missing or corrupt config.yaml / status.json / eval*.json, a
corrupt or truncated log) becomes a one-line reason on that run and never an exception, so
one broken folder cannot take the dashboard down. The dashboard reads run folders only, and
only through `detach.runfolder`: the summary (task, model, seed, samples per iteration), the
shown state (`dead` when a live state's process is gone) and the checks of eval*.json are the
ones `detach-run list` and `detach-run table` apply.
"""

from __future__ import annotations

import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np

from detach.runfolder import files as run_files
from detach.runfolder.eval_result import EvalResult
from detach.runfolder.folder import RunFolder, is_run_folder, read_eval
from detach.runfolder.liveness import DEAD, is_dead
from detach.runfolder.log_tail import LogTail, closed_cleanly
from detach.runfolder.messages import RunSummary, Status
from detach.runfolder.names import LIVE_STATES
from detach.runfolder.summary import read_config_summary


@dataclass
class RunInfo:
    """What the runs table shows about one run folder (equal infos = nothing to redraw)."""

    run_id: str
    path: Path
    task: str = "?"
    model: str = "?"
    seed: int | None = None
    cell: str | None = None
    """The sweep cell (status.json), e.g. `table1/lh1/detach/s0`."""
    origin: str | None = None
    """status.json's run id, written when the run was created: a copied folder shares it."""
    state: str = "unknown"
    iteration: int | None = None
    lh_sr: float | None = None
    """eval.json's `lh_success.rate` (evaluation on the task the run trained on)."""
    started: float | None = None
    updated: float | None = None
    error: str | None = None
    """status.json's error of a failed or interrupted run."""
    dead: bool = False
    """status.json says queued or running, but the process it names is gone (`is_dead`)."""
    samples_per_iteration: int | None = None
    """Environment steps per training iteration (sim.num_envs x train.num_steps_per_env)."""
    problems: tuple[str, ...] = ()
    """Reasons the folder cannot be read completely; any reason makes it 'unreadable'."""
    log_version: tuple = ()
    """(size, mtime) of log.mcap; () without a log. Changes whenever the log grows."""
    eval_version: tuple = ()
    """Changes whenever an eval*.json file changed."""

    @property
    def unreadable(self) -> bool:
        return bool(self.problems)

    @property
    def shown_state(self) -> str:
        return "unreadable" if self.problems else DEAD if self.dead else self.state

    @property
    def live(self) -> bool:
        """status.json's state may still change by itself (a dead run's too: it may be resumed)."""
        return self.state in LIVE_STATES

    @property
    def has_log(self) -> bool:
        return bool(self.log_version) and self.log_version[0] > 0


@dataclass
class _Cached:
    key: tuple[int, int] | None = None
    value: Any = None
    problem: str | None = None
    parses: int = 0


def _stat_key(path: Path) -> tuple[int, int] | None:
    try:
        st = os.stat(path)
    except OSError:
        return None
    return st.st_size, st.st_mtime_ns


@dataclass
class MetricSeries:
    """A run's /metrics as columns: x = iteration (the last message of a repeated
    iteration wins, as after a resume), one float array per numeric key (NaN where an
    iteration lacks the key), and each iteration's log time (Unix seconds)."""

    iterations: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)
    times: np.ndarray = field(default_factory=lambda: np.zeros(0))


class RunReader:
    """Cached view of one run folder; its log is opened only on demand."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.run = RunFolder(path)
        self._files: dict[str, _Cached] = {}
        self._tail: LogTail | None = None
        self._series: tuple[int, MetricSeries] | None = None
        self._log_check: tuple[tuple[int, int] | None, list[str]] = (None, [])
        self.evals: dict[str, EvalResult] = {}
        self._lock = threading.RLock()

    def _read(self, path: Path, read: Callable[[Path], Any]) -> _Cached:
        """`read(path)` (a reader of `detach.runfolder`), again only when the file changed."""
        name = path.name
        entry = self._files.setdefault(name, _Cached())
        key = _stat_key(path)
        if key is None:
            entry.key, entry.value, entry.problem = None, None, f"{name} missing"
        elif key != entry.key:
            entry.key, entry.parses = key, entry.parses + 1
            try:  # bounded, regular files of this folder only, never blocking
                entry.value = read(path)
                entry.problem = None
            except run_files.RunFileError as exc:  # refused unread, or read and malformed
                entry.value = None
                refused = exc.why.startswith(("refused", "expected UTF-8"))
                entry.problem = f"{name} {exc.why}" if refused else f"{name} unreadable ({exc.why})"
            except Exception as exc:  # noqa: BLE001 - any bad file becomes a reason
                entry.value = None
                entry.problem = f"{name} unreadable ({_short(exc)})"
        return entry

    def parse_count(self, name: str) -> int:
        """How often `name` was parsed (tests check that unchanged files are not)."""
        return self._files[name].parses if name in self._files else 0

    def read(self) -> RunInfo:
        with self._lock:
            info = RunInfo(self.path.name, self.path)
            problems: list[str] = []
            status = self._read(self.run.status_path, lambda _path: self.run.status())
            s: Status | None = status.value
            summary, problem = self._summary(s)
            if summary is not None:
                info.task, info.model, info.seed = summary.task, summary.model, summary.seed
                info.samples_per_iteration = summary.samples_per_iteration
            if problem is not None:
                problems.append(problem)
            if s is not None:
                info.state, info.updated, info.started, info.error = s.state, s.updated, s.started, s.error
                info.iteration, info.cell, info.origin = s.iteration, s.cell, s.run_id
                info.dead = is_dead(s)
            else:
                problems.append(status.problem or f"{self.run.status_path.name} unreadable")
            problems += self._read_evals(info)
            problems += self._read_log(info)
            info.problems = tuple(problems)
            return info

    def _summary(self, status: Status | None) -> tuple[RunSummary | None, str | None]:
        """(the run's summary, why config.yaml is unreadable), as `RunFolder.summary` reads
        them: status.json's summary, else config.yaml's (a folder of an earlier version);
        config.yaml is checked either way (re-read only when it changed)."""
        config_path = self.run.config_path
        config = self._read(config_path, lambda _path: read_config_summary(self.path))
        if config.value is None:
            return None, config.problem or f"{config_path.name} unreadable"
        return (status.summary if status is not None and status.summary else config.value), None

    def _read_evals(self, info: RunInfo) -> list[str]:
        problems, versions = [], []
        try:
            names = self.run.evaluation_names()
        except OSError as exc:
            return [f"folder unreadable ({_short(exc)})"]
        self.evals = {}
        for name in names:
            entry = self._read(self.path / name, read_eval)
            versions.append((name, entry.key))
            if entry.value is not None:
                self.evals[name] = entry.value
            elif entry.problem and entry.key is not None:
                problems.append(entry.problem)
        main = self.evals.get(self.run.eval_path.name)
        if main is not None:
            info.lh_sr = main.lh_success.rate
        info.eval_version = tuple(versions)
        return problems

    def _read_log(self, info: RunInfo) -> list[str]:
        key = _stat_key(self.run.log_path)
        info.log_version = key or ()
        if key is None or key[0] == 0:
            return []
        if self._tail is not None:  # open in a browser: read what was appended
            return self._tail_problems(self._tail, info)
        if info.live:
            return []  # still being written: its end is not a footer yet
        checked_key, problems = self._log_check
        if checked_key != key:
            problems = self._check_closed_log(info)
            self._log_check = (key, problems)
        return problems

    def _check_closed_log(self, info: RunInfo) -> list[str]:
        """A finished run's log must start and end with the MCAP magic; if it does not,
        scan it once to say what is wrong (a scan of a healthy log is never needed)."""
        if closed_cleanly(self.run.log_path):
            return []
        tail = LogTail(self.run.log_path)
        try:
            tail.refresh()
        except Exception as exc:  # noqa: BLE001 - a reader bug must not hide the run
            return [f"{tail.path.name} unreadable ({_short(exc)})"]
        return self._tail_problems(tail, info)

    @staticmethod
    def _tail_problems(log: LogTail, info: RunInfo) -> list[str]:
        name = log.path.name
        try:
            log.refresh()
        except Exception as exc:  # noqa: BLE001
            return [f"{name} unreadable ({_short(exc)})"]
        if log.problem:
            return [log.problem]
        if log.size and not info.live and not log.complete:
            read = f"read {len(log.metrics)} iterations"
            if log.pending_bytes:
                return [f"{name} truncated: the last {log.pending_bytes} of {log.size} bytes "
                        f"are a partial record ({read} before the cut)"]
            return [f"{name} truncated: no MCAP footer although the run is {info.state} "
                    f"({read})"]
        return []

    # --- the log, on demand ---------------------------------------------------------------
    @property
    def log(self) -> LogTail:
        """The tailed log (opened on first use, brought up to date on every access)."""
        with self._lock:
            if self._tail is None:
                self._tail = LogTail(self.run.log_path)
            try:
                self._tail.refresh()
            except Exception:  # noqa: BLE001 - LogTail.problem / RunInfo.problems say why
                pass
            return self._tail

    @property
    def log_open(self) -> bool:
        return self._tail is not None

    def close_log(self) -> None:
        """Forget the tailed log (nobody shows this run any more); reopened on demand."""
        with self._lock:
            self._tail, self._series = None, None

    def series(self) -> MetricSeries:
        """The metrics as columns; rebuilt only when new messages arrived."""
        with self._lock:
            log = self.log
            n = len(log.metric_messages)
            if self._series is not None and self._series[0] == n:
                return self._series[1]
            rows = {m.iteration: (m.values, t) for m, t in log.metric_messages}
            its = sorted(rows)
            keys = sorted({k for values, _t in rows.values() for k in values})
            columns = {k: np.array([_num(rows[i][0].get(k)) for i in its], dtype=np.float64)
                       for k in keys}
            times = np.array([rows[i][1] for i in its], dtype=np.float64)
            result = MetricSeries(np.array(its, dtype=np.float64), columns, times)
            self._series = (n, result)
            return result

    def config_text(self) -> str:
        """config.yaml as written (the config view and the diff read it on demand); OSError,
        or RunFileError (one line) for a file that is not a bounded regular file of the run."""
        return run_files.read_text(self.path, self.run.config_path.name)

    def stdout_tail(self, lines: int = 40, max_bytes: int = 64_000) -> str:
        """The last `lines` lines of stdout.log (progress bars reduced to their final state),
        or the one line saying why it is not shown."""
        try:
            data = run_files.read_tail(self.path, self.run.stdout_path.name, max_bytes)
        except run_files.RunFileError as exc:
            return f"({self.run.stdout_path.name} {exc.why})"
        except OSError:
            return ""
        shown = [ln.rsplit("\r", 1)[-1] for ln in data.splitlines() if ln.strip()]
        return "\n".join(shown[-lines:])


def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else np.nan


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    text = text[:160]
    return f"{exc.__class__.__name__}: {text}" if text else exc.__class__.__name__


class RunIndex:
    """All run folders under `runs_dir`, refreshed on demand (the dashboard polls).

    `settled_per_refresh`: None re-checks every run on every refresh; a number re-checks
    that many settled runs per refresh, round-robin (new and live runs always)."""

    def __init__(self, runs_dir: Path, settled_per_refresh: int | None = None) -> None:
        self.runs_dir = Path(runs_dir)
        self.settled_per_refresh = settled_per_refresh
        self.readers: dict[str, RunReader] = {}
        self.infos: dict[str, RunInfo] = {}
        self.changed: set[str] = set()
        """Runs whose info changed (or appeared or disappeared) in the last refresh."""
        self._rotation: list[str] = []
        self._lock = threading.RLock()

    def _folders(self) -> dict[str, Path]:
        """Run folders directly under runs_dir (one directory read; markers are checked
        only for folders not known yet)."""
        try:
            entries = list(os.scandir(self.runs_dir))
        except OSError:
            return {}
        found = {}
        for e in entries:
            try:
                if not e.is_dir():
                    continue
            except OSError:
                continue
            path = Path(e.path)
            if e.name in self.readers or is_run_folder(path):
                found[e.name] = path
        return found

    def _due(self, folders: dict[str, Path]) -> list[str]:
        """Which runs to re-read now: all, or new + live + the next settled ones in turn."""
        if self.settled_per_refresh is None:
            return list(folders)
        due = [n for n in folders if n not in self.infos or self.infos[n].live]
        settled = {n for n in folders if n in self.infos and not self.infos[n].live}
        rotation = [n for n in self._rotation if n in settled]
        in_rotation = set(rotation)
        rotation += sorted(n for n in settled if n not in in_rotation)
        take = rotation[: self.settled_per_refresh]
        self._rotation = rotation[len(take):] + take
        return due + take

    def refresh(self) -> list[RunInfo]:
        """Re-read what is due; new folders appear, deleted ones disappear. Never raises."""
        with self._lock:
            folders = self._folders()
            self.changed = {n for n in self.readers if n not in folders}
            for name in self.changed:
                del self.readers[name]
                self.infos.pop(name, None)
            for name in self._due(folders):
                reader = self.readers.setdefault(name, RunReader(folders[name]))
                try:
                    info = reader.read()
                except Exception as exc:  # noqa: BLE001 - last line of defence
                    info = RunInfo(name, folders[name], problems=(f"unreadable ({_short(exc)})",))
                if self.infos.get(name) != info:
                    self.changed.add(name)
                    self.infos[name] = info
            return [self.infos[n] for n in sorted(self.infos)]

    def snapshot(self) -> dict[str, RunInfo]:
        """The current infos, sorted by run id (oldest first: folder names start with time)."""
        with self._lock:
            return {n: self.infos[n] for n in sorted(self.infos)}

    def reader(self, run_id: str) -> RunReader | None:
        with self._lock:
            return self.readers.get(run_id)

    def close_logs_except(self, keep: set[str]) -> None:
        """Drop the tailed logs of runs no browser shows (their memory goes with them)."""
        with self._lock:
            for name, reader in self.readers.items():
                if name not in keep and reader.log_open:
                    reader.close_log()

    def evals(self, run_ids: list[str] | None = None) -> list[EvalResult]:
        """Every parsed eval*.json of the given runs (all runs if None)."""
        return [e for _run, e in self.evals_by_run(run_ids)]

    def evals_by_run(self, run_ids: list[str] | None = None) -> list[tuple[str, EvalResult]]:
        """(run id, result) of every parsed eval*.json of the given runs (all if None); a
        folder that shares its status.json run id with one listed before it (a copy, `cp -r
        RUN RUN.bak`) is left out, so the tables count a run once as `detach-run table` does."""
        with self._lock:
            ids = sorted(self.readers) if run_ids is None else run_ids
            seen: set[str] = set()
            out = []
            for i in (i for i in ids if i in self.readers):
                origin = self.infos[i].origin if i in self.infos else None
                if origin is not None:
                    if origin in seen:
                        continue
                    seen.add(origin)
                out += [(i, e) for _name, e in sorted(self.readers[i].evals.items())]
            return out
