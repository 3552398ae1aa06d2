"""Tables and the run list from imperfect folders: a sweep cell counts once (its newest
evaluation), impossible or malformed eval.json files are left out with a line saying which,
and one broken file never stops `detach-run list` (docs/RELIABILITY.md)."""

from __future__ import annotations

import json
import os
from pathlib import Path
from typing import Any

import pytest

from detach import cli
from detach.config import resolve
from detach.runfolder.folder import RunFolder, find_runs
from detach.runs.tables_cli import collect_evals
from tests.test_runner_cli import FOLLOW


def _eval(rate: float, trials: int = 10) -> dict[str, Any]:
    """A minimal eval.json of the follow task (rates over `trials` trials)."""
    return {"task": "follow", "trained_on": "follow", "model": "mlp", "seed": 0, "trials": trials,
            "plan": ["follow"],
            "subtasks": [{"index": 0, "skill": "follow", "rate": rate, "ci": [0.0, 1.0], "n": trials}],
            "lh_success": {"rate": rate, "ci": [0.0, 1.0], "n": trials}, "sgr": 0.0}


def _run(parent: Path, data: Any, cell: str | None = None, written: float | None = None) -> RunFolder:
    run = RunFolder.create(parent, resolve(FOLLOW, "mlp"))
    run.set_state("finished", cell=cell)
    run.eval_path.write_text(data if isinstance(data, str) else json.dumps(data))
    if written is not None:
        os.utime(run.eval_path, (written, written))
    return run


def test_a_sweep_cell_evaluated_twice_counts_once_the_newest(tmp_path: Path,
                                                            capsys: pytest.CaptureFixture[str]) -> None:
    cell = "mini/follow/mlp/s0"
    _run(tmp_path, _eval(0.0), cell, written=1_000_000)  # the first sweep's copy of the cell
    _run(tmp_path, _eval(1.0), cell, written=2_000_000)  # a second sweep over the same file
    _run(tmp_path, _eval(0.5))  # a run outside any sweep is its own entry
    evals = collect_evals(find_runs(tmp_path))
    assert sorted(e.lh_success.rate for e in evals) == [0.5, 1.0]
    assert sum(e.trials for e in evals) == 20, "n is not doubled"
    assert "1 older evaluation(s) of a sweep cell left out" in capsys.readouterr().err
    assert cli.main(["table", str(tmp_path), "--kind", "skills", "--task", "follow"]) == 0
    assert "1 older evaluation(s) of a sweep cell left out" in capsys.readouterr().err


BAD_EVALS = {
    "nan rate": json.dumps(_eval(0.5)).replace('"rate": 0.5', '"rate": NaN', 1),
    "rate as text": json.dumps(_eval(0.5)).replace('"rate": 0.5', '"rate": "high"', 1),
    "subtasks null": json.dumps({**_eval(0.5), "subtasks": None}),
    "rate above one": json.dumps(_eval(1.5)),
    "zero trials": json.dumps(_eval(0.5, trials=0)),
    "interval upside down": json.dumps(_eval(0.5)).replace("[0.0, 1.0]", "[0.9, 0.1]", 1),
    "not json": "{rate: high",
    "nested too deeply": "[" * 100_000 + "]" * 100_000,
    "a list": "[1, 2, 3]",
    "binary": "\udcff\udcfe",
}


@pytest.mark.parametrize("name", sorted(BAD_EVALS))
def test_a_bad_eval_json_is_left_out_with_a_line_and_the_rest_still_counts(
        name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = _run(tmp_path, _eval(0.25))
    text = BAD_EVALS[name]
    bad = RunFolder.create(tmp_path, resolve(FOLLOW, "mlp"))
    bad.set_state("finished")
    bad.eval_path.write_bytes(text.encode("utf-8", "surrogateescape"))
    evals = collect_evals(find_runs(tmp_path))
    assert [e.lh_success.rate for e in evals] == [0.25]
    err = capsys.readouterr().err
    assert f"skipped {bad.eval_path}" in err and len(err.strip().splitlines()) == 1
    assert cli.main(["table", str(tmp_path), "--kind", "skills", "--task", "follow"]) == 0
    capsys.readouterr()
    assert cli.main(["list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines()[1:] if not line.startswith(" ")}
    assert rows[good.path.name][-1] == "0.25" and rows[bad.path.name][-1] == "invalid"
    assert f"{bad.path.name}: eval.json ignored:" in out


BAD_STATUS = {
    "binary": b"\x00\x01garbage",
    "not json": b"{state: running",
    "a list": b"[1, 2]",
    "unknown state": b'{"state": "sleeping"}',
    "pid as text": b'{"state": "running", "pid": "x"}',
}


@pytest.mark.parametrize("name", sorted(BAD_STATUS))
def test_a_broken_status_json_is_one_line_naming_the_file_and_hides_no_other_run(
        name: str, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = _run(tmp_path, _eval(0.25))
    bad = _run(tmp_path, _eval(0.75))
    bad.status_path.write_bytes(BAD_STATUS[name])
    assert cli.main(["list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rows = {line.split()[0]: line.split() for line in out.splitlines()[1:] if not line.startswith(" ")}
    assert rows[good.path.name][-1] == "0.25" and rows[bad.path.name][4] == "unreadable"
    (note,) = [line for line in out.splitlines() if line.startswith(f"  {bad.path.name}:")]
    assert "status.json" in note and ("expected" in note or "must be" in note), note
    assert cli.main(["resume", str(bad.path)]) == 2  # no checkpoint: one line, nothing written
    assert len(capsys.readouterr().err.strip().splitlines()) == 1
    assert bad.status_path.read_bytes() == BAD_STATUS[name]


def test_a_run_folder_without_config_yaml_is_listed_and_refused_in_one_line(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    good = _run(tmp_path, _eval(0.25))
    bad = _run(tmp_path, _eval(0.75))
    bad.config_path.unlink()
    assert cli.main(["list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert f"  {bad.path.name}: ConfigError: {bad.config_path}: file not found" in out
    assert any(line.split()[0] == good.path.name and line.split()[-1] == "0.25" for line in out.splitlines())
    for argv in (["resume", str(bad.path)], ["eval", str(bad.path)]):
        assert cli.main(argv) == 2
        err = capsys.readouterr().err.strip().splitlines()
        assert err == [f"detach-run: error: {bad.path}: not a run folder (no config.yaml)"]


def test_a_table_of_a_task_never_evaluated_is_one_line_not_an_empty_table(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _run(tmp_path, _eval(0.25))
    out = tmp_path / "tables"
    assert cli.main(["table", str(tmp_path), "--task", "lh9", "--out", str(out)]) == 2
    captured = capsys.readouterr()
    assert captured.err.strip().splitlines() == [
        f"detach-run: error: {tmp_path}: --task: no evaluation of task 'lh9' (evaluated: follow)"]
    assert captured.out == "" and not out.exists(), "nothing printed or written"


def test_a_table_whose_default_task_no_run_reached_writes_nothing_and_says_so(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A sweep in progress (phase A evaluated on follow, no LH1 cell yet): Table I would be an
    empty table that reads like a result."""
    _run(tmp_path, _eval(1.0))
    out = tmp_path / "tables"
    assert cli.main(["table", str(tmp_path), "--kind", "skills", "--out", str(out)]) == 0
    captured = capsys.readouterr()
    assert "skills: no run evaluated on this table's task yet (evaluated: follow" in captured.err
    assert captured.out == "" and not list(out.glob("*_skills.*"))
    assert cli.main(["table", str(tmp_path), "--kind", "skills", "--task", "follow", "--out", str(out)]) == 0
    assert "| 1.00 [" in capsys.readouterr().out and (out / f"{tmp_path.name}_skills_follow.csv").exists()


def test_a_table_out_that_is_a_file_is_one_line_before_anything_is_printed(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    _run(tmp_path, _eval(1.0))
    blocker = tmp_path / "a-file"
    blocker.write_text("not a folder")
    for out in (blocker, blocker / "tables"):
        assert cli.main(["table", str(tmp_path), "--task", "follow", "--out", str(out)]) == 2
        captured = capsys.readouterr()
        assert captured.out == "", "no table printed before the error"
        assert captured.err.strip().splitlines() == [
            f"detach-run: error: {out}: --out: expected a folder, found a file ({blocker})"]
    assert blocker.read_text() == "not a folder"


def _lh1_eval(rate: float, trials: int = 10) -> dict[str, Any]:
    """A minimal eval.json of LH1 (every subtask at `rate`)."""
    plan = ["follow", "carry", "climb", "sit"]
    return {"task": "lh1", "trained_on": "lh1", "model": "mlp", "seed": 0, "trials": trials, "plan": plan,
            "subtasks": [{"index": i, "skill": s, "rate": rate, "ci": [0.0, 1.0], "n": trials}
                         for i, s in enumerate(plan)],
            "lh_success": {"rate": rate, "ci": [0.0, 1.0], "n": trials}, "sgr": 0.0}


def test_a_sweep_table_reads_only_the_evaluations_the_sweep_asks_of_each_cell(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A phase-A cell evaluated by hand on LH1 (a diagnosis: the Follow policy tried on LH1)
    must not pool into the LH1 column of the sweep's table, which is the LH1 cell's."""
    from detach.runs.sweep_config import load_sweep
    from detach.runs.sweep_graph import cells
    from tests.test_sweep_protocol import write_sweep

    sweep = write_sweep(tmp_path)
    keys = {c.stage: c.key for c in cells(load_sweep(sweep, preset="tiny"), sweep)}
    runs = tmp_path / "runs"
    runs.mkdir()
    follow = _run(runs, _eval(1.0), keys["follow"])
    (follow.path / "eval_lh1.json").write_text(json.dumps(_lh1_eval(0.0)))
    _run(runs, _lh1_eval(1.0), keys["lh1"])
    assert cli.main(["table", str(sweep), "--runs", str(runs), "--preset", "tiny", "--trial-set", "development",
                     "--out", str(tmp_path / "t")]) == 0
    assert "1 evaluation(s) on a task the sweep does not evaluate their cell on left out" in capsys.readouterr().err
    csv = (tmp_path / "t" / "mini_dev.csv").read_text().splitlines()
    assert csv[1].split(",")[1:8] == ["1.0", "1.0", "1.0", "1.0", "1.0", "1.0", "10 (1 seed: s0)"], csv
