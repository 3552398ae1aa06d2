"""Running a piece of work inside a run folder with honest status bookkeeping.

`run_job` moves status.json through running -> finished | failed | interrupted, copies
everything printed to stdout.log (the console still sees it), and turns a crash into
state `failed` with the error message, Ctrl-C / SIGTERM into `interrupted`. The work function
is expected to checkpoint before raising `StopRequested` (the training runner does).
"""

from __future__ import annotations

import contextlib
import sys
import traceback
from typing import Callable, TextIO

from detach.runs.folder import RunFolder
from detach.train.runner import StopRequested

EXIT_OK, EXIT_FAILED, EXIT_INTERRUPTED = 0, 1, 130


class _Tee:
    """A text stream writing to the console stream and a log file."""

    def __init__(self, console: TextIO, log: TextIO) -> None:
        self.console, self.log = console, log

    def write(self, text: str) -> int:
        self.console.write(text)
        self.log.write(text)
        self.log.flush()
        return len(text)

    def flush(self) -> None:
        self.console.flush()
        self.log.flush()

    def isatty(self) -> bool:
        return self.console.isatty()

    def fileno(self) -> int:
        return self.console.fileno()


@contextlib.contextmanager
def captured_output(run: RunFolder):
    """Tee stdout and stderr into the run's stdout.log (appending across resumes)."""
    with open(run.stdout_path, "a", encoding="utf-8", buffering=1) as log:
        old_out, old_err = sys.stdout, sys.stderr
        sys.stdout, sys.stderr = _Tee(old_out, log), _Tee(old_err, log)
        try:
            yield
        finally:
            sys.stdout, sys.stderr = old_out, old_err


def run_job(run: RunFolder, work: Callable[[RunFolder], None]) -> int:
    """Run `work(run)` with status tracking; returns a process exit code."""
    run.set_state("running", error=None)
    with captured_output(run):
        try:
            work(run)
        except (StopRequested, KeyboardInterrupt) as exc:
            reason = str(exc) or exc.__class__.__name__
            run.set_state("interrupted", error=f"stopped by {reason}")
            print(f"detach-run: interrupted ({reason}); resume with: detach-run --resume "
                  f"{run.path}", file=sys.stderr)
            return EXIT_INTERRUPTED
        except Exception as exc:  # noqa: BLE001 - recorded, then reported as a failure
            traceback.print_exc()
            run.set_state("failed", error=f"{exc.__class__.__name__}: {exc}")
            print(f"detach-run: run failed: {exc.__class__.__name__}: {exc} ({run.path})",
                  file=sys.stderr)
            return EXIT_FAILED
    run.set_state("finished")
    return EXIT_OK
