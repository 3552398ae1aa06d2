"""Sweeps at cluster scale: progress n/N with elapsed time and ETA, a failed cell's stderr tail,
and the submitit launcher (SLURM) on submitit's local executor."""

from __future__ import annotations

import dataclasses
import io
import re
import textwrap
from pathlib import Path

import pytest

from detach import cli
from detach.runfolder.folder import find_runs
from detach.config import ConfigError
from detach.runs.sweep import run_sweep
from detach.runs.sweep_config import load_sweep
from detach.runs.sweep_graph import cell_work, cells
from detach.runs.sweep_launchers import stderr_tail
from detach.runs.sweep_eta import SweepClock

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "train.max_iterations=2"]


def one_stage_sweep(tmp_path: Path, overrides: list[str]) -> Path:
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
          follow: []
        eval_trials: 2
        overrides: [{', '.join(overrides)}]
        """))
    return sweep


def test_a_failed_cell_prints_its_progress_and_the_tail_of_its_stderr(tmp_path: Path,
                                                                      capsys: pytest.CaptureFixture[str]) -> None:
    sweep = one_stage_sweep(tmp_path, [*TINY, "train.init_from=/nowhere/run"])
    assert cli.main(["--sweep", str(sweep), "--out", str(tmp_path / "runs")]) == 1
    out = capsys.readouterr().out
    elapsed = r"elapsed [\d.]+ (s|min|h)"
    assert re.search(rf"\[0/1\] follow/mlp/s0/\w+: start \({elapsed}, ETA \?\)", out), out
    assert re.search(rf"\[1/1\] follow/mlp/s0/\w+: FAILED \(exit 2; {elapsed}, ETA 0 s\)", out), out
    assert re.search(r"\n    \| detach-run: error: .*train.init_from: /nowhere/run is neither a run folder", out), out


def test_stderr_tail_shows_a_progress_bar_as_a_terminal_would() -> None:
    err = io.BytesIO(b"start\ntrain: 1%\rtrain: 50%\rtrain: 99%\n" + b"x\n" * 3 + b"Traceback\nValueError: bad\n")
    assert stderr_tail(err, lines=6).splitlines() == ["train: 99%", "x", "x", "x", "Traceback", "ValueError: bad"]


@pytest.mark.slow
def test_the_submitit_launcher_runs_cells_as_jobs(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                                  capsys: pytest.CaptureFixture[str]) -> None:
    pytest.importorskip("submitit")
    monkeypatch.setenv("DETACH_SUBMITIT_CLUSTER", "local")
    monkeypatch.setenv("DETACH_SUBMITIT", '{"timeout_min": 30}')
    sweep = one_stage_sweep(tmp_path, TINY)
    out = tmp_path / "runs"
    assert run_sweep(sweep, out, jobs=1, launcher="slurm") == 0
    runs = find_runs(out)
    assert len(runs) == 1 and runs[0].status().state == "finished"
    printed = capsys.readouterr().out
    assert "(slurm)" in printed and re.search(r"\[1/1\] follow/mlp/s0/\w+: done \(elapsed", printed), printed
    assert list((out / ".submitit").glob("*_log.out")), "submitit's job logs"
    # a bad parameter is a one-line error before anything runs
    monkeypatch.setenv("DETACH_SUBMITIT", "[1, 2]")
    with pytest.raises(ConfigError, match="DETACH_SUBMITIT: expected a JSON object"):
        run_sweep(one_stage_sweep(tmp_path / "b", [*TINY, "seed=1"]), tmp_path / "b" / "runs", launcher="slurm")


def test_the_eta_weighs_cells_by_their_env_steps_and_counts_running_cells() -> None:
    """The sweep of 2026-12-05 printed 'ETA 7.4 h' after its first cell and took 2.2 h: the
    mean time per finished cell counted the 25-iteration Carry cells as 400-iteration Follow
    cells and ignored the Follow cell running beside it."""
    now = [0.0]
    clock = SweepClock(jobs=2, now=lambda: now[0])
    for cell, work in (("follow/a", 800.0), ("follow/b", 800.0), ("carry/a", 200.0), ("carry/b", 200.0)):
        clock.add(cell, work)
    clock.start("follow/a")
    clock.start("follow/b")
    assert clock.eta_s() is None and clock.progress().endswith("ETA ?")
    now[0] = 800.0  # one second per unit of work
    clock.end("follow/a")
    # follow/b has run as long as follow/a took: nothing left of it; the two Carry cells share 2 slots
    assert clock.eta_s() == pytest.approx(200.0)
    clock.end("follow/b")
    clock.start("carry/a")
    now[0] = 850.0
    assert clock.eta_s() == pytest.approx((150.0 + 200.0) / 2)
    clock.skip("carry/b")  # its parent failed: nothing of it is left to run
    assert clock.eta_s() == pytest.approx(150.0)
    assert clock.progress() == "elapsed 14 min, ETA 2 min"


def test_a_cells_work_is_its_training_samples_plus_its_evaluation_steps() -> None:
    sweep_path = ROOT / "configs/sweeps/table1.yaml"
    sweep = load_sweep(sweep_path, preset="laptop")
    by_stage = {c.stage: c for c in cells(sweep, sweep_path) if c.model == "detach"}
    follow, carry = by_stage["follow"], by_stage["carry"]
    assert cell_work(follow, trials=100) == 400 * 64 * 32 + 100 * 1200  # follow.yaml's 40 s episodes
    # the preset's 20 s Carry episodes; its start's two choices at 50 validation trials each and
    # its eight kept checkpoints (every 5th of 40) at 100 each
    assert cell_work(carry, trials=100) == 40 * 256 * 32 + (100 + 2 * 50 + 8 * 100) * 600
    broken = dataclasses.replace(carry, overrides=(*carry.overrides, "train.no_such_key=1"))
    assert cell_work(broken, trials=100) is None  # counted as a mean cell; the run itself says why
