"""Kill at any moment: SIGTERM while environments start or during the final evaluation ends
`interrupted` with exit code 130; a killed run's stale pid is `dead`, not `running`; a pid of
another host is never looked up here (docs/RELIABILITY.md)."""

from __future__ import annotations

import json
import os
import signal
import subprocess
import sys
import textwrap
import time
from pathlib import Path

import pytest

from detach import cli
from detach.config import resolve
from detach.runfolder.folder import RunFolder, find_runs
from detach.runfolder.liveness import owner_alive
from tests.test_runner_cli import FOLLOW, ROOT, TINY

SLOW_STEP = """
import signal, sys, time
import detach.runs.session as session

def slow(*_args, **_kwargs):
    # The kernel hands a process's SIGTERM to any thread; CPython then runs the handler in the
    # main thread at its next bytecode, so one 120 s sleep hid it for 120 s whenever another
    # thread (the heartbeat's) got it: a flake once. Blocked here, it always goes to another
    # thread, and the step returns to Python every 0.1 s as real start-up work does.
    signal.pthread_sigmask(signal.SIG_BLOCK, [signal.SIGTERM])
    print("SLOW STEP", flush=True)
    for _ in range(1200):
        time.sleep(0.1)

session.{target} = slow
from detach import cli
sys.exit(cli.main(sys.argv[1:]))
"""


def _terminate_during(target: str, out: Path, *extra: str) -> tuple[int, str, RunFolder]:
    """Run detach-run with `session.<target>` replaced by a long sleep, SIGTERM it there."""
    script = textwrap.dedent(SLOW_STEP.format(target=target))
    proc = subprocess.Popen([sys.executable, "-c", script, FOLLOW, "--model", "mlp", "--out", str(out),
                             "--trials", "1", *extra, *TINY],
                            cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE, text=True)
    try:
        deadline = time.time() + 300
        for line in proc.stdout:  # type: ignore[union-attr]
            if "SLOW STEP" in line or time.time() > deadline:
                break
        proc.send_signal(signal.SIGTERM)
        try:
            _out, err = proc.communicate(timeout=60)
        except subprocess.TimeoutExpired:  # say where it hung: its output so far
            proc.kill()
            stdout, stderr = proc.communicate()
            raise AssertionError(f"still running 60 s after SIGTERM\nstdout:\n{stdout[-3000:]}\n"
                                 f"stderr:\n{stderr[-3000:]}")
    finally:
        proc.kill()
    (run,) = find_runs(out)
    return proc.returncode, err, run


def test_sigterm_during_environment_start_up_ends_interrupted(tmp_path: Path) -> None:
    code, err, run = _terminate_during("build_runner", tmp_path, "train.max_iterations=1")
    assert code == 130, err
    assert "interrupted (SIGTERM)" in err and "Traceback" not in err
    status = run.status()
    assert status.state == "interrupted" and status.error == "stopped by SIGTERM"


def test_sigterm_during_the_final_evaluation_ends_interrupted(tmp_path: Path) -> None:
    code, err, run = _terminate_during("evaluate_run", tmp_path, "train.max_iterations=1")
    assert code == 130, err
    status = run.status()
    assert status.state == "interrupted" and status.error == "stopped by SIGTERM"
    assert run.latest_checkpoint() is not None, "training had finished: --resume only evaluates"


def _run_with_status(tmp_path: Path, **fields: object) -> RunFolder:
    run = RunFolder.create(tmp_path, resolve(FOLLOW, "mlp"))
    run.set_state("running", iteration=5)
    status = json.loads(run.status_path.read_text())
    status.update(fields)
    run.status_path.write_text(json.dumps(status))
    return run


def _dead_pid() -> int:
    proc = subprocess.Popen([sys.executable, "-c", "pass"])
    proc.wait()
    return proc.pid


def test_a_killed_run_lists_as_dead_with_the_command_that_resumes_it(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    run = _run_with_status(tmp_path, pid=_dead_pid())
    assert cli.main(["list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert [line.split()[4] for line in out.splitlines()[1:2]] == ["dead"]
    assert f"detach-run --resume {run.path}" in out  # no checkpoint yet: it restarts from iteration 0


def test_a_reused_pid_is_not_the_run(tmp_path: Path) -> None:
    """kill -9 an hour ago, then another process got the pid: it started after the run's
    last status update, which its owner always writes after starting."""
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(60)"])
    try:
        run = _run_with_status(tmp_path, pid=sleeper.pid, started=time.time() - 7200,
                               updated=time.time() - 3600)
        assert not run.owner_alive()
        fresh = _run_with_status(tmp_path, pid=sleeper.pid, started=time.time() - 7200)
        assert fresh.owner_alive(), "an owner resumed long after the run started is alive"
        for group in (-1, -os.getpgid(0)):  # kill(-n, 0) would ask about a process group
            assert not _run_with_status(tmp_path, pid=group).owner_alive()
    finally:
        sleeper.kill()
        sleeper.wait()


def test_a_pid_of_another_host_is_judged_by_its_heartbeat(tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--no-eval",
                     "train.max_iterations=1", *TINY]) == 0
    (run,) = find_runs(tmp_path)
    assert run.status().host, "status.json names the machine of its pid"
    status = json.loads(run.status_path.read_text())
    dead_here = _dead_pid()  # dead on this machine, alive (as far as we know) on the other
    status.update(state="running", pid=dead_here, host="elsewhere.example", updated=time.time())
    run.status_path.write_text(json.dumps(status))
    capsys.readouterr()
    assert cli.main(["resume", str(run.path), "--dry-run"]) == 2
    err = capsys.readouterr().err
    assert "still running on host elsewhere.example" in err and len(err.strip().splitlines()) == 1
    status.update(updated=time.time() - 3600)  # its heartbeat stopped an hour ago
    run.status_path.write_text(json.dumps(status))
    assert not owner_alive(run.status())
    assert cli.main(["resume", str(run.path), "--dry-run"]) == 0
    # and a live pid of this machine under another host's name is not taken for that run
    status.update(pid=os.getppid(), updated=time.time() - 3600)
    run.status_path.write_text(json.dumps(status))
    assert not run.owner_alive()
