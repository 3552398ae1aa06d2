"""configs/sweeps/humanoid.yaml: the humanoid's Follow as sweep cells, played on test trials,
with its departures from the paper named in the table row."""

from __future__ import annotations

import csv
from pathlib import Path

from detach import cli
from detach.runfolder.folder import find_runs
from detach.runs.sweep_config import load_sweep
from detach.runs.sweep_graph import cells
from detach.train.run_config import resolve_run

ROOT = Path(__file__).resolve().parents[1]
SWEEP = ROOT / "configs/sweeps/humanoid.yaml"


def test_the_laptop_cells_train_the_humanoid_and_end_without_the_assist() -> None:
    sweep = load_sweep(SWEEP, preset="laptop")
    (cell0, cell1) = cells(sweep, SWEEP)
    assert (cell0.seed, cell1.seed) == (0, 1) and cell0.model == "mlp"
    cfg = resolve_run(cell0.task, cell0.model, list(cell0.overrides), presets=list(cell0.presets))
    assert cfg.env.character == "humanoid" and cfg.env.fall_rule == "body"
    assist = cfg.train.balance_assist
    unassisted = cfg.train.max_iterations - assist.hold_iterations - assist.fade_iterations
    assert assist.torque > 0 and unassisted >= 300  # the policy ends on its own balance
    assert cfg.rewards.power_coeff == 0 and not cfg.model.learn_noise_std and cfg.train.clone_start.rounds > 0


def test_a_quick_sweep_plays_the_test_trials_and_names_its_departures(tmp_path: Path) -> None:
    out, tables = tmp_path / "runs", tmp_path / "tables"
    assert cli.main(["sweep", str(SWEEP), "--quick", "--runs", str(out)]) == 0
    (run,) = find_runs(out)
    assert run.config().env.character == "humanoid" and (run.path / "eval.test.json").exists()
    assert cli.main(["table", str(SWEEP), "--preset", "quick", "--runs", str(out), "--task", "follow",
                     "--out", str(tables)]) == 0
    (row,) = csv.DictReader((tables / "humanoid_follow.csv").open())
    assert row["method"] == "MLP + critic warm-up + cloned start + balance assist + no power penalty"
