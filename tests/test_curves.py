"""Learning curves drawn from a run's log (`detach-run table SWEEP --out DIR` writes them)."""

from __future__ import annotations

from pathlib import Path

from detach import cli
from detach.runs.curves import run_curve, write_sweep_curves
from detach.runfolder.folder import find_runs

TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "env.episode_length=6",
        "train.max_iterations=4", "--no-eval"]


def test_curves_of_a_run_are_its_logged_metrics_drawn_per_stage(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    assert cli.main(["configs/tasks/follow.yaml", "--model", "mlp", "--out", str(out), *TINY]) == 0
    run = find_runs(out)[0]
    curve = run_curve(run, "mlp", 0)
    assert curve is not None and curve.label == "mlp s0" and curve.iterations == [0, 1, 2, 3]
    assert {"mean reward", "episode length", "success: 0_follow"} <= set(curve.values)
    lengths = [v for v in curve.values["episode length"] if v == v]
    assert lengths and all(0 < v <= 6 for v in lengths)  # episodes of at most 6 steps ended
    notes: list[str] = []
    written = write_sweep_curves({"follow/mlp/s0/abc": run, "carry/mlp/s0/def": run}, tmp_path / "plots",
                                 "mini", "mini", notes.append)
    assert sorted(p.name for p in written) == ["curves_mini_carry.png", "curves_mini_follow.png"] and not notes
    assert all(p.read_bytes()[:8] == b"\x89PNG\r\n\x1a\n" and p.stat().st_size > 10_000 for p in written)
    assert not list((tmp_path / "plots").glob(".*.tmp"))


def test_a_figure_is_redrawn_only_when_its_runs_or_their_logs_change(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    for seed in ("0", "1"):
        assert cli.main(["configs/tasks/follow.yaml", "--model", "mlp", "--seed", seed, "--out", str(out), *TINY]) == 0
    first, second = sorted(find_runs(out), key=lambda r: r.path.name)
    plots, notes = tmp_path / "plots", []
    both = {"follow/mlp/s0/a": first, "follow/mlp/s1/b": second}
    written = write_sweep_curves(both, plots, "mini", "mini", notes.append)
    assert [p.name for p in written] == ["curves_mini_follow.png"]
    drawn = (plots / "curves_mini_follow.png").read_bytes()
    assert write_sweep_curves(both, plots, "mini", "mini", notes.append) == []  # nothing changed: not redrawn
    assert notes == ["curves_mini_follow.png: up to date (its 2 runs' logs unchanged since it was drawn)"]
    assert (plots / "curves_mini_follow.png").read_bytes() == drawn
    # another sweep's table in the same folder writes its own figure, not over this one
    other = write_sweep_curves(both, plots, "table3", "t3", notes.append)
    assert [p.name for p in other] == ["curves_table3_follow.png"]
    assert (plots / "curves_mini_follow.png").read_bytes() == drawn
    # another set of runs of the same sweep, another title, a log that grew: each draws it again
    assert len(write_sweep_curves({"follow/mlp/s0/a": first}, plots, "mini", "mini", notes.append)) == 1
    assert len(write_sweep_curves({"follow/mlp/s0/a": first}, plots, "mini", "other", notes.append)) == 1
    with open(first.log_path, "ab") as log:
        log.write(b"\0")
    assert len(write_sweep_curves({"follow/mlp/s0/a": first}, plots, "mini", "other", notes.append)) == 1
    assert len(notes) == 1


def test_the_checkpoint_a_run_chose_as_its_policy_is_marked(tmp_path: Path, monkeypatch) -> None:
    """With `train.select_checkpoint_trials`, the curve carries the chosen iteration (a dashed
    line in the figure), and a new choice redraws the figure."""
    from types import SimpleNamespace

    from detach.runs import validation

    scores = iter([0.1, 0.8, 0.3, 0.2])
    monkeypatch.setattr(validation, "run_evaluation",
                        lambda *_a, **_k: SimpleNamespace(lh_mean=SimpleNamespace(rate=next(scores))))
    out = tmp_path / "runs"
    assert cli.main(["configs/tasks/follow.yaml", "--model", "mlp", "--out", str(out), *TINY, "train.save_interval=1",
                     "train.keep_checkpoints.last=0", "train.select_checkpoint_trials=1"]) == 0
    run = find_runs(out)[0]
    curve = run_curve(run, "mlp", 0)
    assert curve is not None and curve.selected == 1
    notes: list[str] = []
    cells = {"carry/mlp/s0/a": run}
    assert len(write_sweep_curves(cells, tmp_path / "plots", "mini", "mini", notes.append)) == 1
    run.selection_path.write_text(run.selection_path.read_text().replace("model_1.pt", "model_2.pt"))
    assert run_curve(run, "mlp", 0).selected == 2
    assert len(write_sweep_curves(cells, tmp_path / "plots", "mini", "mini", notes.append)) == 1 and not notes
