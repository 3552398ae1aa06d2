"""A sweep never starts a cell that another live process is still training, with or without a
checkpoint, whoever started it (another sweep whose driver was killed, a `detach-run --cell`
by hand, a Ray or Slurm sweep, which hold no cell lock): it waits for that process, then takes
the cell as it finds it (issue 19, item 5; docs/RELIABILITY.md)."""

from __future__ import annotations

import json
import re
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from detach.config import resolve
from detach.runfolder.folder import RunFolder, find_runs
from detach.runs.sweep import run_sweep
from detach.runs.sweep_config import load_sweep
from detach.runs.sweep_graph import cells
from tests.test_runner_cli import FOLLOW
from tests.test_sweep_protocol import ROOT, TINY


def _one_stage_sweep(tmp_path: Path, models: str = "[mlp]") -> Path:
    """A sweep of one follow cell per model (seed 0): nothing to train once those are done."""
    sweep = tmp_path / "sweeps" / "one.yaml"
    sweep.parent.mkdir(parents=True, exist_ok=True)
    sweep.write_text(textwrap.dedent(f"""\
        name: one
        models: {models}
        seeds: [0]
        table: skills
        stages:
          - {{name: follow, task: {ROOT / 'configs/tasks/follow.yaml'}}}
        eval:
          follow: [{ROOT / 'configs/tasks/follow.yaml'}]
        presets:
          tiny: {{eval_trials: 2, overrides: [{', '.join(TINY)}]}}
        """))
    return sweep


@pytest.mark.parametrize("with_checkpoint", [False, True], ids=["no checkpoint yet", "with a checkpoint"])
def test_a_cell_running_in_another_process_is_waited_for_not_run_twice_nor_failed(
        tmp_path: Path, with_checkpoint: bool) -> None:
    sweep = _one_stage_sweep(tmp_path)
    out = tmp_path / "runs"
    (cell,) = cells(load_sweep(sweep, preset="tiny"), sweep)
    run = RunFolder.create(out, resolve(FOLLOW, "mlp"))
    run.set_state("running", cell=cell.key, iteration=1)  # owned by this (live) test process
    if with_checkpoint:
        (run.checkpoints / "model_1.pt").write_bytes(b"not read: the cell is not touched while its owner lives")
    proc = subprocess.Popen([sys.executable, "-m", "detach.cli", "--sweep", str(sweep), "--preset", "tiny",
                             "--out", str(out)], cwd=ROOT, stdout=subprocess.PIPE, stderr=subprocess.PIPE,
                            text=True)
    lines: list[str] = []
    reader = threading.Thread(target=lambda: lines.extend(iter(proc.stdout.readline, "")), daemon=True)
    reader.start()
    try:
        deadline = time.monotonic() + 180
        while not any("waiting" in line for line in lines):
            assert proc.poll() is None, f"the sweep ended instead of waiting: {lines} {proc.stderr.read()}"
            assert time.monotonic() < deadline, f"the sweep never said it waits: {lines}"
            time.sleep(0.5)
        time.sleep(3.0)  # more than one look at the cell
        assert [r.path for r in find_runs(out)] == [run.path], "the cell was started a second time"
        assert proc.poll() is None
        # The owner finishes the cell; the sweep finds it done and starts nothing.
        run.eval_path.write_text(json.dumps({"task": "follow"}))
        run.set_state("finished")
        code = proc.wait(timeout=120)
    finally:
        proc.kill()
        reader.join(timeout=5)
    text = "".join(lines)
    assert code == 0, text + proc.stderr.read()
    assert f"waiting: {cell.key} is running in process" in text
    assert "FAILED" not in text and f"{cell.key}: done" in text
    assert [r.path for r in find_runs(out)] == [run.path]


class _FakeRay:
    """Ray's API as the sweep uses it, with no cluster: the first submitted cell ends at once,
    the second only once the sweep has printed that the first is done."""

    def __init__(self, capsys: pytest.CaptureFixture[str]) -> None:
        self.capsys, self.refs, self.printed, self.waits = capsys, [], "", 0

    def is_initialized(self) -> bool:
        return True

    def remote(self, **_options: object):
        def wrap(_fn: object) -> object:
            fake = self

            class Remote:
                @staticmethod
                def remote(*_args: object) -> object:
                    fake.refs.append(object())
                    return fake.refs[-1]
            return Remote
        return wrap

    def wait(self, refs: list, num_returns: int = 1, timeout: float | None = None) -> tuple[list, list]:
        self.waits += 1
        assert self.waits < 50, f"the first cell's end was never reported while the second ran: {self.printed!r}"
        self.printed += self.capsys.readouterr().out
        first_reported = re.search(r"\[1/2\] \S+: done", self.printed)
        ready = [r for r in refs if r is self.refs[0] or (first_reported and r is self.refs[1])][:num_returns]
        return ready, [r for r in refs if r not in ready]

    def get(self, _ref: object) -> tuple[int, str]:
        return 0, ""


def test_a_ray_sweep_reports_each_cell_as_it_ends(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                 capsys: pytest.CaptureFixture[str]) -> None:
    """With Ray, a cell's end is printed when it ends, not when the last cell does."""
    fake = _FakeRay(capsys)
    monkeypatch.setitem(sys.modules, "ray", fake)
    assert run_sweep(_one_stage_sweep(tmp_path, "[mlp, cml]"), tmp_path / "runs", jobs=2, launcher="ray") == 0
    printed = fake.printed + capsys.readouterr().out
    assert len(fake.refs) == 2 and re.search(r"\[2/2\] \S+: done", printed), printed
