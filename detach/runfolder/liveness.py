"""Whether a run is really alive: status.json's `running` is what the run last said, and a
`kill -9` leaves it behind.

`owner_alive` asks the operating system when the recorded process is on this host and
trusts the heartbeat (`updated`, refreshed by `detach.runs.job` every `HEARTBEAT_S`) when it
is on another host sharing the runs folder. `shown_state` is the state every reader shows
(`detach-run list`, the dashboard): `dead` for a live state whose owner is gone.
"""

from __future__ import annotations

import os
import socket
import time
from pathlib import Path

from detach.runfolder.messages import Status
from detach.runfolder.names import LIVE_STATES

HEARTBEAT_S = 30.0
"""How often a running job refreshes status.json's `updated` (detach.runs.job)."""
STALE_AFTER_S = 600.0
"""A run on another host whose status.json is older than this is taken for dead (generous:
clocks of machines sharing a folder may disagree by minutes)."""
DEAD = "dead"
"""The shown state of a run whose status says queued or running but whose process is gone."""


def this_host() -> str:
    return socket.gethostname()


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


def is_dead(status: Status, now: float | None = None) -> bool:
    """A live state with a recorded owner that is gone (a run queued without a pid is not)."""
    return status.state in LIVE_STATES and bool(status.pid) and not owner_alive(status, now)


def shown_state(status: Status, now: float | None = None) -> str:
    """status.json's state, or `DEAD` when `is_dead`."""
    return DEAD if is_dead(status, now) else status.state
