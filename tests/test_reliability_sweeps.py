"""A sweep never starts a cell that another live process is still training, with or without a
checkpoint, whoever started it (another sweep whose driver was killed, a `detach-run --cell`
by hand, a Ray or Slurm sweep, which hold no cell lock): it waits for that process, then takes
the cell as it finds it (issue 19, item 5; docs/RELIABILITY.md)."""

from __future__ import annotations

import json
import subprocess
import sys
import textwrap
import threading
import time
from pathlib import Path

import pytest

from detach.config import resolve
from detach.runs.folder import RunFolder, find_runs
from detach.runs.sweep import cells, load_sweep
from tests.test_runner_cli import FOLLOW
from tests.test_sweep_protocol import ROOT, TINY


def _one_stage_sweep(tmp_path: Path) -> Path:
    """A sweep of one follow cell (mlp, seed 0): nothing to train once that cell is done."""
    sweep = tmp_path / "sweeps" / "one.yaml"
    sweep.parent.mkdir(parents=True, exist_ok=True)
    sweep.write_text(textwrap.dedent(f"""\
        name: one
        models: [mlp]
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
