"""The runs/ folder as the dashboard sees it: one cached reader per run folder.

Each refresh stats every file of every run and re-parses only files whose (size, mtime)
changed; log.mcap is tailed incrementally (server.log_tail). Whatever is wrong with a run
(missing or corrupt config.yaml / status.json / eval*.json, a corrupt or truncated log)
becomes a one-line reason on that run and never an exception, so one broken folder cannot
take the dashboard down. The dashboard reads run folders only, never a training process.
"""

from __future__ import annotations

import json
import os
import threading
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Callable

import numpy as np
import yaml

from detach.run_contract import (
    CONFIG_FILE, EVAL_FILE, LIVE_STATES, LOG_FILE, STATUS_FILE, EvalResult, Status, is_eval_file,
)
from detach.runs.folder import find_runs
from server.log_tail import LogTail


@dataclass
class RunInfo:
    """What the runs table shows about one run folder."""

    run_id: str
    path: Path
    task: str = "?"
    model: str = "?"
    seed: int | None = None
    state: str = "unknown"
    iteration: int | None = None
    lh_sr: float | None = None
    """eval.json's `lh_success.rate` (evaluation on the task the run trained on)."""
    updated: float | None = None
    error: str | None = None
    """status.json's error of a failed or interrupted run."""
    problems: tuple[str, ...] = ()
    """Reasons the folder cannot be read completely; any reason makes it 'unreadable'."""
    log_version: int = 0
    """Changes whenever new log messages were read (metrics, scene or frames)."""
    eval_version: tuple = ()
    """Changes whenever an eval*.json file changed."""

    @property
    def unreadable(self) -> bool:
        return bool(self.problems)

    @property
    def shown_state(self) -> str:
        return "unreadable" if self.problems else self.state

    @property
    def live(self) -> bool:
        return self.state in LIVE_STATES


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


def _parse_status(text: str) -> Status:
    return Status.from_json(json.loads(text))


def _parse_config(text: str) -> dict[str, Any]:
    """Only the keys the dashboard shows; deliberately lenient so that runs written by an
    older schema still list (the strict loader is for running, not for browsing)."""
    data = yaml.load(text, Loader=getattr(yaml, "CSafeLoader", yaml.SafeLoader))
    if not isinstance(data, dict):
        raise ValueError("expected a mapping")
    missing = [k for k in ("task_name", "model_name", "seed") if k not in data]
    if missing:
        raise ValueError(f"missing keys {', '.join(missing)}")
    return {"task": str(data["task_name"]), "model": str(data["model_name"]),
            "seed": data["seed"]}


def _parse_eval(text: str) -> EvalResult:
    return EvalResult.from_json(json.loads(text))


@dataclass
class MetricSeries:
    """A run's /metrics as columns: x = iteration (the last message of a repeated
    iteration wins, as after a resume), one float array per numeric key."""

    iterations: np.ndarray
    columns: dict[str, np.ndarray] = field(default_factory=dict)


class RunReader:
    """Cached view of one run folder."""

    def __init__(self, path: Path) -> None:
        self.path = path
        self.log = LogTail(path / LOG_FILE)
        self._files: dict[str, _Cached] = {}
        self._series: tuple[int, MetricSeries] | None = None
        self.evals: dict[str, EvalResult] = {}

    def _read(self, name: str, parse: Callable[[str], Any]) -> _Cached:
        entry = self._files.setdefault(name, _Cached())
        key = _stat_key(self.path / name)
        if key is None:
            entry.key, entry.value, entry.problem = None, None, f"{name} missing"
        elif key != entry.key:
            entry.key, entry.parses = key, entry.parses + 1
            try:
                entry.value = parse((self.path / name).read_text(encoding="utf-8"))
                entry.problem = None
            except Exception as exc:  # noqa: BLE001 - any bad file becomes a reason
                entry.value = None
                entry.problem = f"{name} unreadable ({_short(exc)})"
        return entry

    def parse_count(self, name: str) -> int:
        """How often `name` was parsed (tests check that unchanged files are not)."""
        return self._files[name].parses if name in self._files else 0

    def read(self) -> RunInfo:
        info = RunInfo(self.path.name, self.path)
        problems: list[str] = []
        config = self._read(CONFIG_FILE, _parse_config)
        if config.value:
            info.task, info.model, info.seed = (config.value["task"], config.value["model"],
                                                config.value["seed"])
        else:
            problems.append(config.problem or f"{CONFIG_FILE} unreadable")
        status = self._read(STATUS_FILE, _parse_status)
        if status.value:
            s = status.value
            info.state, info.updated, info.error = s.state, s.updated, s.error
            info.iteration = s.iteration
        else:
            problems.append(status.problem or f"{STATUS_FILE} unreadable")
        problems += self._read_evals(info)
        problems += self._read_log(info)
        info.problems = tuple(problems)
        return info

    def _read_evals(self, info: RunInfo) -> list[str]:
        problems, versions = [], []
        try:
            names = sorted(n for n in os.listdir(self.path) if is_eval_file(n))
        except OSError as exc:
            return [f"folder unreadable ({_short(exc)})"]
        self.evals = {}
        for name in names:
            entry = self._read(name, _parse_eval)
            versions.append((name, entry.key))
            if entry.value is not None:
                self.evals[name] = entry.value
            elif entry.problem and entry.key is not None:
                problems.append(entry.problem)
        main = self.evals.get(EVAL_FILE)
        if main is not None:
            info.lh_sr = main.lh_success.rate
        info.eval_version = tuple(versions)
        return problems

    def _read_log(self, info: RunInfo) -> list[str]:
        log = self.log
        try:
            log.refresh()
        except Exception as exc:  # noqa: BLE001 - a reader bug must not hide the run
            return [f"{LOG_FILE} unreadable ({_short(exc)})"]
        info.log_version = log.version
        if log.problem:
            return [log.problem]
        if log.size and not info.live and not log.complete:
            read = f"read {len(log.metrics)} iterations"
            if log.pending_bytes:
                return [f"{LOG_FILE} truncated: the last {log.pending_bytes} of {log.size} bytes "
                        f"are a partial record ({read} before the cut)"]
            return [f"{LOG_FILE} truncated: no MCAP footer although the run is {info.state} "
                    f"({read})"]
        if log.metrics and info.iteration is None:
            info.iteration = int(log.metrics[-1].get("iteration", 0))
        return []

    def series(self) -> MetricSeries:
        """The metrics as columns; rebuilt only when new messages arrived."""
        n = len(self.log.metrics)
        if self._series is not None and self._series[0] == n:
            return self._series[1]
        rows: dict[int, dict[str, Any]] = {}
        for m in self.log.metrics:
            it = m.get("iteration")
            if isinstance(it, (int, float)):
                rows[int(it)] = m
        its = sorted(rows)
        keys = sorted({k for m in rows.values() for k, v in m.items()
                       if k != "iteration" and isinstance(v, (int, float))
                       and not isinstance(v, bool)})
        columns = {k: np.array([_num(rows[i].get(k)) for i in its], dtype=np.float64)
                   for k in keys}
        result = MetricSeries(np.array(its, dtype=np.float64), columns)
        self._series = (n, result)
        return result


def _num(v: Any) -> float:
    return float(v) if isinstance(v, (int, float)) and not isinstance(v, bool) else np.nan


def _short(exc: BaseException) -> str:
    text = str(exc).strip().splitlines()[0] if str(exc).strip() else ""
    text = text[:160]
    return f"{exc.__class__.__name__}: {text}" if text else exc.__class__.__name__


class RunIndex:
    """All run folders under `runs_dir`, refreshed on demand (the dashboard polls)."""

    def __init__(self, runs_dir: Path) -> None:
        self.runs_dir = Path(runs_dir)
        self.readers: dict[str, RunReader] = {}
        self.infos: dict[str, RunInfo] = {}
        self._lock = threading.RLock()

    def refresh(self) -> list[RunInfo]:
        """Re-read what changed; new folders appear, deleted ones disappear. Never raises."""
        with self._lock:
            try:
                folders = {r.path.name: r.path for r in find_runs(self.runs_dir)}
            except OSError:
                folders = {}
            for name in list(self.readers):
                if name not in folders:
                    del self.readers[name]
                    self.infos.pop(name, None)
            for name, path in folders.items():
                reader = self.readers.setdefault(name, RunReader(path))
                try:
                    self.infos[name] = reader.read()
                except Exception as exc:  # noqa: BLE001 - last line of defence
                    self.infos[name] = RunInfo(name, path,
                                               problems=(f"unreadable ({_short(exc)})",))
            return [self.infos[n] for n in sorted(self.infos)]

    def reader(self, run_id: str) -> RunReader | None:
        with self._lock:
            return self.readers.get(run_id)

    def evals(self, run_ids: list[str] | None = None) -> list[EvalResult]:
        """Every parsed eval*.json of the given runs (all runs if None)."""
        with self._lock:
            ids = sorted(self.readers) if run_ids is None else run_ids
            return [e for i in ids if i in self.readers
                    for _name, e in sorted(self.readers[i].evals.items())]
