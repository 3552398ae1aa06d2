"""A sweep cell is a job file of API calls that `python -m detach.runs.worker` runs (every
launcher alike), and `detach-run play` finds its live viewer through an entry point
(issue 58, item 3; the sweeps themselves: test_sweep_protocol.py, test_sweep_cluster.py)."""

from __future__ import annotations

import inspect
import subprocess
import sys
import tomllib
from importlib.metadata import EntryPoint
from pathlib import Path
from types import SimpleNamespace

import pytest

from detach.config import ConfigError
from detach.runs import actions
from detach.runs.job_file import JOB_ACTIONS, JobStep, read_job, write_job
from detach.runs.sweep_config import load_sweep
from detach.runs.sweep_graph import cells
from detach.runs.sweep_jobs import cell_steps, job_path
from detach.runs.worker import ACTIONS, main

ROOT = Path(__file__).resolve().parents[1]


def test_a_new_cells_job_is_one_train_call_of_the_api(tmp_path: Path) -> None:
    sweep_path = ROOT / "configs/sweeps/table1.yaml"
    sweep = load_sweep(sweep_path, preset="laptop")
    by_stage = {c.stage: c for c in cells(sweep, sweep_path) if c.model == "detach"}
    carry = by_stage["carry"]
    parent = SimpleNamespace(path=tmp_path / "follow-run")
    (step,) = cell_steps(carry, None, parent, tmp_path / "runs", trials=100, device="cpu")
    assert step.action == "train"
    inspect.signature(actions.train).bind(**step.arguments)  # the arguments are the function's
    args = step.arguments
    assert (args["task"], args["model"], args["seed"], args["cell"]) == (str(carry.task), "detach", 0, carry.key)
    assert args["overrides"][-1] == f"train.init_from={parent.path.resolve()}"
    assert args["trials"] == 100 and args["test_offset"] == carry.test_offset and args["presets"] == list(carry.presets)
    path = write_job(job_path(tmp_path / "runs", carry), carry.key, [step])
    assert path.parent == tmp_path / "runs" / ".jobs" and "/" not in path.name
    assert read_job(path) == [step]


def test_every_action_of_a_job_is_a_function_of_the_api() -> None:
    assert tuple(ACTIONS) == JOB_ACTIONS
    for name, function in ACTIONS.items():
        assert function is getattr(actions, name)


def test_a_bad_job_file_is_a_one_line_error(tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    bad = tmp_path / "bad.json"
    bad.write_text('{"cell": "x", "steps": [{"action": "rm", "arguments": {}}]}')
    assert main([str(bad)]) == 2
    err = capsys.readouterr().err.splitlines()
    assert len(err) == 1 and err[0].startswith("detach-run: error: ") and "one of train, resume, evaluate" in err[0]
    assert main([str(tmp_path / "missing.json")]) == 2
    assert "cannot read the job file" in capsys.readouterr().err
    with pytest.raises(ConfigError):
        read_job(bad)
    assert write_job(tmp_path / "j.json", "x", [JobStep("evaluate", {"target": "r"})]).exists()


def test_the_worker_is_a_module_entry(tmp_path: Path) -> None:
    proc = subprocess.run([sys.executable, "-m", "detach.runs.worker"], capture_output=True, text=True, cwd=ROOT)
    assert proc.returncode == 2 and "usage: python -m detach.runs.worker JOBFILE" in proc.stderr


def test_the_live_viewer_is_the_dashboards_entry_point(monkeypatch: pytest.MonkeyPatch) -> None:
    declared = tomllib.loads((ROOT / "pyproject.toml").read_text())["project"]["entry-points"]
    target = declared[actions.VIEWER_ENTRY_POINTS]["live"]
    from server.play_view import play_live

    assert EntryPoint("live", target, actions.VIEWER_ENTRY_POINTS).load() is play_live
    monkeypatch.setattr("importlib.metadata.entry_points", lambda group: [
        EntryPoint("live", target, group)] if group == actions.VIEWER_ENTRY_POINTS else [])
    assert actions._live_viewer() is play_live
    monkeypatch.setattr("importlib.metadata.entry_points", lambda group: [])
    with pytest.raises(ConfigError, match="no live viewer installed .*--video FILE.mp4 needs none"):
        actions._live_viewer()
