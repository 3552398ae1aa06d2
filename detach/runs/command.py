"""How a detach command ends, whichever entry runs it (`detach-run`, a sweep's worker).

A user's mistake is a `ConfigError`: one line on stderr, exit code 2. SIGTERM anywhere
(start-up included) ends the command like Ctrl-C, exit code 130: a sweep stops its cells with
SIGTERM, and each run checkpoints and ends `interrupted` (`detach.runs.job`). Tracebacks are
reserved for bugs.
"""

from __future__ import annotations

import signal
import sys
import threading
from typing import Callable

from detach.config import ConfigError

EXIT_USAGE = 2
EXIT_INTERRUPTED = 130


def _interrupt(signum: int, _frame: object) -> None:
    raise KeyboardInterrupt(signal.Signals(signum).name)


def _fail(prog: str, exc: Exception) -> int:
    print(f"{prog}: error: {exc}", file=sys.stderr)
    return EXIT_USAGE


def run_command(body: Callable[[], int], prog: str = "detach-run") -> int:
    """`body()`'s exit code, a `ConfigError` as one line (2), SIGTERM or Ctrl-C as 130."""
    if threading.current_thread() is not threading.main_thread():  # no signal handlers off the main thread
        try:
            return body()
        except ConfigError as exc:
            return _fail(prog, exc)
    previous = signal.signal(signal.SIGTERM, _interrupt)
    try:
        try:
            return body()
        except ConfigError as exc:
            return _fail(prog, exc)
    except KeyboardInterrupt as exc:
        print(f"{prog}: interrupted ({str(exc) or 'SIGINT'})", file=sys.stderr)
        return EXIT_INTERRUPTED
    finally:
        signal.signal(signal.SIGTERM, previous)
