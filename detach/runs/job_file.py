"""A sweep cell's job file, `<runs>/.jobs/<cell>.json`: the calls of the API that bring the cell
to done, which `python -m detach.runs.worker JOBFILE` makes.

`{"cell": KEY, "steps": [{"action": "train" | "resume" | "evaluate", "arguments": {...}}]}`:
each step is a function of `detach.runs.actions` and its keyword arguments (paths as strings).
The sweep writes it (`detach.runs.sweep_jobs`), every launcher runs the same command on it.
"""

from __future__ import annotations

import json
import sys
from dataclasses import dataclass, field
from pathlib import Path
from typing import Any, Sequence

from detach.config import ConfigError
from detach.runfolder.atomic import atomic_write_json

WORKER_MODULE = "detach.runs.worker"
"""What a launcher runs: `python -m WORKER_MODULE JOBFILE`."""

JOB_ACTIONS = ("train", "resume", "evaluate")
"""The functions of `detach.runs.actions` a step may name."""

MAX_JOB_BYTES = 1 << 20


@dataclass(frozen=True)
class JobStep:
    """One call of the API: `actions.<action>(**arguments)`."""

    action: str
    arguments: dict[str, Any] = field(default_factory=dict)


def worker_command(job: Path) -> list[str]:
    """The argv that runs the job file `job` (in this interpreter)."""
    return [sys.executable, "-m", WORKER_MODULE, str(job)]


def write_job(path: Path, cell: str, steps: Sequence[JobStep]) -> Path:
    """Write the job file of `cell` (whole, atomically); returns its path."""
    path.parent.mkdir(parents=True, exist_ok=True)
    atomic_write_json(path, {"cell": cell, "steps": [{"action": s.action, "arguments": s.arguments} for s in steps]})
    return path


def read_job(path: Path) -> list[JobStep]:
    """The steps of a job file; ConfigError naming the file for one that is not a job."""
    try:
        if path.stat().st_size > MAX_JOB_BYTES:
            raise ConfigError(f"job file larger than {MAX_JOB_BYTES} bytes", str(path))
        data = json.loads(path.read_text(encoding="utf-8"))
    except (OSError, ValueError) as exc:
        raise ConfigError(f"cannot read the job file ({exc})", str(path)) from None
    steps = data.get("steps") if isinstance(data, dict) else None
    if not isinstance(steps, list):
        raise ConfigError("expected a job file: {\"cell\": ..., \"steps\": [...]}", str(path))
    out = []
    for i, step in enumerate(steps):
        if not (isinstance(step, dict) and step.get("action") in JOB_ACTIONS
                and isinstance(step.get("arguments"), dict)):
            raise ConfigError(f"steps[{i}]: expected {{\"action\": one of {', '.join(JOB_ACTIONS)}, "
                              f"\"arguments\": {{...}}}}, found {step!r}", str(path))
        out.append(JobStep(step["action"], step["arguments"]))
    return out
