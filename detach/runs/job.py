"""Running a piece of work inside a run folder with honest status bookkeeping.

`run_job` moves status.json through running -> finished | failed | interrupted, copies
everything printed to stdout.log (the console still sees it), and turns a crash into
state `failed` with the error message, Ctrl-C / SIGTERM into `interrupted` (exit code 130)
at any moment of the job: while environments start, while training (the runner checkpoints
first and raises `StopRequested`) and during the final evaluation. While it runs, a heartbeat
thread refreshes status.json's `updated`, which tells other machines sharing the runs
folder that the run is alive. Faults of the machine (a full disk, a read-only folder) are
reported in one line; tracebacks are kept for bugs and go to stdout.log only.
"""

from __future__ import annotations

import contextlib
import errno
import signal
import sys
import threading
import traceback
from typing import Callable, Iterator, TextIO

from detach.config import ConfigError
from detach.runfolder.folder import RunFolder
from detach.runfolder.liveness import HEARTBEAT_S
from detach.train.runner import StopRequested

EXIT_OK, EXIT_FAILED, EXIT_USAGE, EXIT_INTERRUPTED = 0, 1, 2, 130
DISK_ERRNOS = (errno.ENOSPC, errno.EDQUOT, errno.EFBIG, errno.EROFS, errno.EACCES, errno.EPERM, errno.EIO)
"""OSErrors that are the machine's fault, not a bug: reported without a traceback."""


class _Tee:
    """A text stream writing to the console stream and a log file. A log that cannot be
    written (a full disk) is dropped rather than breaking every later print."""

    def __init__(self, console: TextIO, log: TextIO) -> None:
        self.console, self.log = console, log
        self.log_ok = True

    def write(self, text: str) -> int:
        self.console.write(text)
        self.write_log(text)
        return len(text)

    def write_log(self, text: str) -> None:
        """Only to stdout.log (tracebacks: the console gets one line)."""
        if not self.log_ok:
            return
        try:
            self.log.write(text)
            self.log.flush()
        except (OSError, ValueError):
            self.log_ok = False

    def flush(self) -> None:
        self.console.flush()
        if self.log_ok:
            try:
                self.log.flush()
            except (OSError, ValueError):
                self.log_ok = False

    def isatty(self) -> bool:
        return self.console.isatty()

    def fileno(self) -> int:
        return self.console.fileno()


@contextlib.contextmanager
def captured_output(run: RunFolder) -> Iterator[_Tee]:
    """Tee stdout and stderr into the run's stdout.log (appending across resumes)."""
    log = open(run.stdout_path, "a", encoding="utf-8", buffering=1)
    old_out, old_err = sys.stdout, sys.stderr
    err = _Tee(old_err, log)
    sys.stdout, sys.stderr = _Tee(old_out, log), err
    try:
        yield err
    finally:
        sys.stdout, sys.stderr = old_out, old_err
        with contextlib.suppress(OSError):
            log.close()


def _raise_stop(signum: int, _frame: object) -> None:
    raise StopRequested(signal.Signals(signum).name)


@contextlib.contextmanager
def stop_on_sigterm() -> Iterator[None]:
    """SIGTERM raises `StopRequested` (as Ctrl-C raises KeyboardInterrupt), so a job stopped
    outside the training loop still ends `interrupted` instead of dying silently with 143.
    The training loop installs its own handler (checkpoint first) and restores this one."""
    if threading.current_thread() is not threading.main_thread():
        yield
        return
    previous = signal.signal(signal.SIGTERM, _raise_stop)
    try:
        yield
    finally:
        signal.signal(signal.SIGTERM, previous)


class Heartbeat:
    """Refreshes the run's status.json every `interval` seconds from a daemon thread."""

    def __init__(self, run: RunFolder, interval: float = HEARTBEAT_S) -> None:
        self.run, self.interval = run, interval
        self._stop = threading.Event()
        self._thread = threading.Thread(target=self._beat, name="detach-heartbeat", daemon=True)

    def _beat(self) -> None:
        while not self._stop.wait(self.interval):
            self.run.heartbeat()

    def __enter__(self) -> "Heartbeat":
        self._thread.start()
        return self

    def __exit__(self, *exc: object) -> None:
        self._stop.set()
        self._thread.join(timeout=5)


def machine_fault(exc: BaseException) -> OSError | None:
    """The OSError (in `exc` or its causes) that is the machine's fault, if any."""
    seen = 0
    while exc is not None and seen < 10:
        if isinstance(exc, OSError) and exc.errno in DISK_ERRNOS:
            return exc
        exc, seen = exc.__cause__ or exc.__context__, seen + 1
    return None


def _describe(exc: BaseException) -> str:
    fault = machine_fault(exc)
    if fault is not None:
        where = f" writing {fault.filename}" if fault.filename else ""
        return f"{fault.strerror or errno.errorcode.get(fault.errno, 'OSError')}{where}"
    return f"{exc.__class__.__name__}: {exc}"


def _mark(run: RunFolder, state: str, **fields: object) -> None:
    """Record the final state; a folder that cannot be written any more (a full disk) is
    said in one line instead of a second traceback."""
    try:
        run.set_state(state, **fields)  # type: ignore[arg-type]
    except OSError as exc:
        print(f"detach-run: could not record state '{state}' in {run.status_path} "
              f"({exc.strerror or exc})", file=sys.stderr)


def run_job(run: RunFolder, work: Callable[[RunFolder], None]) -> int:
    """Run `work(run)` with status tracking; returns a process exit code."""
    with stop_on_sigterm():
        try:
            run.remove_stale_temp_files()
            run.set_state("running", error=None)
            with captured_output(run) as err, Heartbeat(run):
                return _run_captured(run, work, err)
        except (StopRequested, KeyboardInterrupt) as exc:  # before the output was captured
            _mark(run, "interrupted", error=f"stopped by {str(exc) or exc.__class__.__name__}")
            return EXIT_INTERRUPTED
        except OSError as exc:  # the folder cannot be written at all (read-only, full)
            print(f"detach-run: cannot write the run folder {run.path} ({exc.strerror or exc})",
                  file=sys.stderr)
            return EXIT_FAILED


def _run_captured(run: RunFolder, work: Callable[[RunFolder], None], err: _Tee) -> int:
    try:
        work(run)
    except (StopRequested, KeyboardInterrupt) as exc:
        reason = str(exc) or exc.__class__.__name__
        _mark(run, "interrupted", error=f"stopped by {reason}")
        print(f"detach-run: interrupted ({reason}); resume with: detach-run --resume "
              f"{run.path}", file=sys.stderr)
        return EXIT_INTERRUPTED
    except ConfigError as exc:  # a bad checkpoint or config found while working: the user's to fix
        _mark(run, "failed", error=str(exc))
        print(f"detach-run: error: {exc}", file=sys.stderr)
        return EXIT_USAGE
    except Exception as exc:  # noqa: BLE001 - recorded, then reported as a failure
        message = _describe(exc)
        if machine_fault(exc) is None:
            traceback.print_exc()
        else:
            err.write_log(traceback.format_exc())
        _mark(run, "failed", error=message)
        print(f"detach-run: run failed: {message} ({run.path})", file=sys.stderr)
        return EXIT_FAILED
    _mark(run, "finished")
    return EXIT_OK
