"""`python -m detach.runs.worker JOBFILE`: one sweep cell's steps, run through the API.

A sweep decides what brings a cell to done (`detach.runs.sweep_jobs.cell_steps`: the
evaluations a finished cell lacks, a resume, or a new run) and writes it as a job file
(`detach.runs.job_file`). Every launcher (a local process, a Ray task, a SLURM job) runs this
entry on that file, so a cell runs the functions `detach-run` calls, with the same messages
and exit codes (2: a user error, 130: interrupted); the first step that does not succeed ends
the job.
"""

from __future__ import annotations

import sys
from pathlib import Path
from typing import Any, Callable, Mapping, Sequence

from detach.runs import actions
from detach.runs.command import EXIT_USAGE, run_command
from detach.runs.job_file import WORKER_MODULE, JobStep, read_job

ACTIONS: Mapping[str, Callable[..., Any]] = {
    "train": actions.train, "resume": actions.resume, "evaluate": actions.evaluate}
"""The function of each action a job file may name (`detach.runs.job_file.JOB_ACTIONS`)."""


def run_step(step: JobStep) -> int:
    """Run one step; its exit code (a run's job code for train and resume, else 0)."""
    result = ACTIONS[step.action](**step.arguments)
    return result.code if isinstance(result, actions.RunOutcome) else 0


def run_job_file(path: Path) -> int:
    """Run the job's steps in order until one does not succeed; that one's exit code."""
    for step in read_job(path):
        code = run_step(step)
        if code != 0:
            return code
    return 0


def main(argv: Sequence[str] | None = None) -> int:
    argv = list(sys.argv[1:] if argv is None else argv)
    if len(argv) != 1 or argv[0].startswith("-"):
        print(f"usage: python -m {WORKER_MODULE} JOBFILE  (a sweep writes <runs>/.jobs/<cell>.json)", file=sys.stderr)
        return EXIT_USAGE
    return run_command(lambda: run_job_file(Path(argv[0])))


if __name__ == "__main__":
    sys.exit(main())
