"""Where a sweep's cells run: a local pool of processes, Ray tasks or SLURM jobs, each running
`python -m detach.runs.worker JOBFILE` on the cell's job file (`detach.runs.sweep_jobs`).

Every pool has `submit(work) -> Future` of (exit code, the last lines of the worker's stderr);
the remote ones also `resolve(futures)`, completing those whose task or job ended. A stopped
sweep (`stop_children`) passes SIGTERM on to its local workers and starts no new one.
"""

from __future__ import annotations

import contextlib
import json
import os
import signal
import subprocess
import tempfile
import threading
import time
from concurrent.futures import Future, ThreadPoolExecutor
from pathlib import Path
from typing import BinaryIO, Protocol

from detach.runs.job_file import worker_command
from detach.config.yaml_source import ConfigError


class CellTask(Protocol):
    """One cell as the scheduler hands it to a pool (`detach.runs.sweep.CellWork`)."""

    cwd: str

    def job(self) -> str | None:
        """Decide and write the cell's job file (None: nothing to do)."""

    def __call__(self) -> tuple[int, str]:
        """Run the cell here, under its lock."""


CHILDREN: set[subprocess.Popen] = set()
"""Workers of this sweep now running: a stopped sweep passes its SIGTERM on to them."""
STOPPING = threading.Event()


def run_worker(job: str | None, cwd: str, env: dict[str, str] | None = None) -> tuple[int, str]:
    """Run a cell's job file in a worker process (None: nothing to do); (exit code, the last
    lines of its stderr)."""
    if job is None:
        return 0, ""
    if STOPPING.is_set():
        from detach.runs.job import EXIT_INTERRUPTED

        return EXIT_INTERRUPTED, "the sweep was stopped"
    with tempfile.TemporaryFile("w+b") as err:  # a file, not a pipe: hours of progress bar stay on disk
        proc = subprocess.Popen(worker_command(Path(job)), cwd=cwd, env=env, stdout=subprocess.DEVNULL, stderr=err)
        CHILDREN.add(proc)
        try:
            proc.wait()
        finally:
            CHILDREN.discard(proc)
        return proc.returncode, stderr_tail(err)


TAIL_LINES = 15
"""Lines of a failed cell's stderr that the sweep prints."""


def stderr_tail(err: BinaryIO, lines: int = TAIL_LINES, max_bytes: int = 64 * 1024) -> str:
    """The last `lines` lines of a stderr file, each line as a terminal would show it (a
    progress bar's carriage returns keep only its last state)."""
    err.seek(0, os.SEEK_END)
    size = err.tell()
    err.seek(max(0, size - max_bytes))
    text = err.read().decode("utf-8", "replace")
    shown = [line.rstrip("\r").rsplit("\r", 1)[-1].rstrip() for line in text.split("\n")]
    return "\n".join([line for line in shown if line][-lines:])


def stop_children() -> None:
    """SIGTERM to every running cell (each checkpoints and ends `interrupted`); no new cell or
    command starts. Ctrl-C reaches the cells by itself (same process group); SIGTERM does not."""
    STOPPING.set()
    for proc in list(CHILDREN):
        if proc.poll() is None:
            proc.send_signal(signal.SIGTERM)


def cell_env(jobs: int) -> dict[str, str]:
    """Parallel cells share the cores: each torch gets cores // jobs threads (torch reads
    OMP_NUM_THREADS for its default) unless the user has set it."""
    env = dict(os.environ)
    env.setdefault("OMP_NUM_THREADS", str(max(1, (os.cpu_count() or 1) // max(jobs, 1))))
    return env


class LocalPool:
    """Cells on `jobs` threads of this process, each running its worker process (under the
    cell's lock: `CellWork.__call__`)."""

    def __init__(self, jobs: int) -> None:
        self.pool = ThreadPoolExecutor(max_workers=max(jobs, 1))
        self.jobs = jobs

    def submit(self, work: CellTask) -> Future:
        return self.pool.submit(work)

    def close(self) -> None:
        self.pool.shutdown(wait=True)


class RayPool:
    """Each cell's worker as one Ray task (one CPU). Joins the cluster of `RAY_ADDRESS` if
    set, else starts a local Ray with `jobs` CPUs. On a cluster, the runs folder must be a file
    system every node sees and the project installed on every node."""

    def __init__(self, jobs: int) -> None:
        try:
            import ray
        except ImportError:
            raise ConfigError("--launcher ray needs Ray: pip install 'detach[ray]'") from None
        self.ray = ray
        if not ray.is_initialized():
            address = os.environ.get("RAY_ADDRESS")
            ray.init(address=address, num_cpus=None if address else max(jobs, 1),
                     include_dashboard=False, log_to_driver=False)
        self.remote = ray.remote(num_cpus=1)(run_worker)
        self.jobs = jobs

    def submit(self, work: CellTask) -> Future:
        """The cell's job, decided and written here, runs remotely (no cell lock: Ray runs each cell of
        this sweep once, and another process's sweep is kept out by the sweep lock only)."""
        future: Future = Future()
        future.ref = self.remote.remote(work.job(), work.cwd)  # type: ignore[attr-defined]
        return future

    def resolve(self, futures: set[Future]) -> None:
        """Complete the futures whose Ray tasks finished, as they finish (`ray.wait` for the
        first, then every other one already done); a task that died is a failed cell."""
        pending = {f.ref: f for f in futures if not f.done()}  # type: ignore[attr-defined]
        if not pending:
            return
        ready, rest = self.ray.wait(list(pending), num_returns=1, timeout=1.0)
        if ready and rest:
            more, _ = self.ray.wait(rest, num_returns=len(rest), timeout=0)
            ready = [*ready, *more]
        for ref in ready:
            try:
                result = self.ray.get(ref)
            except Exception as exc:  # noqa: BLE001 - the worker died or the task raised
                result = (1, f"Ray task failed: {type(exc).__name__}: {exc}")
            pending[ref].set_result(result)

    def close(self) -> None:
        """Ray stays up for other sweeps of this process."""


class SubmititPool:
    """Each cell's worker as one SLURM job through submitit (the [slurm] extra). The
    executor is submitit's `AutoExecutor` (SLURM where `sbatch` exists, else local processes);
    `DETACH_SUBMITIT_CLUSTER` forces one of submitit's clusters (`slurm`, `local`, `debug`) and
    `DETACH_SUBMITIT` holds the executor's parameters as JSON (e.g. {"slurm_partition": "gpu",
    "timeout_min": 1440, "gpus_per_node": 1, "cpus_per_task": 16}). Job logs go to
    <runs>/.submitit/. As with Ray, the runs folder and the project must be on every node."""

    def __init__(self, jobs: int, out: Path) -> None:
        try:
            import submitit
        except ImportError:
            raise ConfigError("--launcher slurm needs submitit: pip install 'detach[slurm]'") from None
        try:
            params = json.loads(os.environ.get("DETACH_SUBMITIT", "{}") or "{}")
        except json.JSONDecodeError as exc:
            raise ConfigError(f"DETACH_SUBMITIT: not JSON ({exc})") from None
        if not isinstance(params, dict):
            raise ConfigError("DETACH_SUBMITIT: expected a JSON object of executor parameters")
        self.folder = out / ".submitit"
        self.executor = submitit.AutoExecutor(folder=self.folder,
                                              cluster=os.environ.get("DETACH_SUBMITIT_CLUSTER") or None)
        params.setdefault("timeout_min", 7 * 24 * 60)
        params.setdefault("name", "detach-sweep")
        try:
            self.executor.update_parameters(**params)
        except (TypeError, ValueError) as exc:
            raise ConfigError(f"DETACH_SUBMITIT: {exc}") from None
        self.jobs = jobs
        self.submitted: list = []

    def submit(self, work: CellTask) -> Future:
        """The cell's job, decided and written here, runs as one SLURM job (no cell lock, as with Ray)."""
        future: Future = Future()
        future.job = self.executor.submit(run_worker, work.job(), work.cwd)  # type: ignore[attr-defined]
        self.submitted.append(future.job)  # type: ignore[attr-defined]
        return future

    def resolve(self, futures: set[Future]) -> None:
        """Complete the futures whose jobs ended (polled; a job that died is a failed cell
        with the tail of its log)."""
        ended = False
        for future in futures:
            job = future.job  # type: ignore[attr-defined]
            if future.done() or not job.done():
                continue
            ended = True
            try:
                future.set_result(job.result())
            except Exception as exc:  # noqa: BLE001 - the job failed or was cancelled
                log = (job.stderr() or "") if hasattr(job, "stderr") else ""
                lines = [line for line in log.splitlines() if line.strip()][-TAIL_LINES:]
                future.set_result((1, "\n".join([f"job {job.job_id} failed: {type(exc).__name__}", *lines])))
        if not ended:
            time.sleep(1.0)

    def close(self) -> None:
        """Jobs that still run are the scheduler's (a stopped sweep cancels them first)."""

    def cancel(self) -> None:
        """Cancel the jobs of this sweep that have not ended (Ctrl-C / SIGTERM of the sweep:
        SLURM sends them SIGTERM, and each run checkpoints and ends `interrupted`)."""
        for job in self.submitted:
            if not job.done():
                with contextlib.suppress(Exception):
                    job.cancel(check=False)


Pool = LocalPool | RayPool | SubmititPool


def make_pool(launcher: str, jobs: int, out: Path) -> Pool:
    """The pool of `--launcher local|ray|slurm`."""
    if launcher == "ray":
        return RayPool(jobs)
    if launcher == "slurm":
        return SubmititPool(jobs, out)
    return LocalPool(jobs)
