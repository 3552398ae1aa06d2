"""`train.select_checkpoint_trials`: a run's policy is its best kept checkpoint on validation trials.

The bug this guards: a later stage of the protocol peaks and then drifts, and every reader
of a run's policy (evaluation, a later stage's `init_from`, play, export) took the newest
checkpoint, so a Carry cell handed on and reported its drifted end instead of its best.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from types import SimpleNamespace

import pytest

from detach import cli
from detach.runs import validation
from detach.runs.checkpoint_choice import select_checkpoint
from detach.runfolder.folder import RunFolder, find_runs
from detach.train.checkpoints import find_init_checkpoint, newest_readable_checkpoint, run_policy_checkpoint

ROOT = Path(__file__).resolve().parents[1]
FOLLOW = str(ROOT / "configs/tasks/follow.yaml")
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "eval.trials=2", "train.save_interval=1", "train.keep_checkpoints.last=0"]


def _scripted_scores(monkeypatch: pytest.MonkeyPatch, scores: list[float]) -> list[int]:
    """Validation trials score the checkpoints (oldest first) with `scores`; returns the
    trial counts each call was asked for."""
    asked: list[int] = []

    def fake_evaluation(_env, _policy, trials, _cfg, **_kw):
        asked.append(trials)
        return SimpleNamespace(lh_mean=SimpleNamespace(rate=scores[len(asked) - 1]))

    monkeypatch.setattr(validation, "run_evaluation", fake_evaluation)
    return asked


def _train(out: Path, *extra: str) -> RunFolder:
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, *extra]) == 0
    (run,) = find_runs(out)
    return run


def test_the_best_checkpoint_on_validation_trials_is_the_runs_policy(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    asked = _scripted_scores(monkeypatch, [0.2, 0.9, 0.5])
    run = _train(tmp_path / "runs", "train.max_iterations=3", "train.select_checkpoint_trials=3")
    assert asked == [3, 3, 3]
    selection = json.loads(run.selection_path.read_text())
    assert selection["checkpoint"] == "model_1.pt" and selection["iteration"] == 1
    assert selection["scores"] == {"0": 0.2, "1": 0.9, "2": 0.5} and selection["trials"] == 3
    assert selection["seed"] == 0 + validation.VALIDATION_SEED_OFFSET
    said = capsys.readouterr().out
    assert "by iteration: 0: 0.20, 1: 0.90, 2: 0.50; the run's policy is model_1.pt" in said, said
    # every reader of the run's policy takes the selected checkpoint, resuming does not
    evaluation = json.loads(run.eval_path.read_text())
    assert evaluation["checkpoint"] == "checkpoints/model_1.pt" and evaluation["iteration"] == 1
    assert find_init_checkpoint(str(run.path)) == (run.checkpoints / "model_1.pt", run.path)
    assert run_policy_checkpoint(run.path) == run.checkpoints / "model_1.pt"
    assert newest_readable_checkpoint(run.path) == run.checkpoints / "model_2.pt"
    assert cli.main(["export", str(run.path), "--format", "init"]) == 0
    assert (run.path / "exported/policy_1.init.pt").is_file()

    # resuming trains on from the newest and chooses again among all kept checkpoints
    _scripted_scores(monkeypatch, [0.2, 0.9, 0.5, 0.95])
    assert cli.main(["resume", str(run.path), "train.max_iterations=4", "--no-eval"]) == 0
    said = capsys.readouterr().out
    assert "resumed from model_2.pt" in said, said
    assert json.loads(run.selection_path.read_text())["checkpoint"] == "model_3.pt"


def test_a_tie_keeps_the_newest_and_real_trials_score_every_checkpoint(tmp_path: Path) -> None:
    """Untrained, every checkpoint scores 0 on the real validation trials: nothing tells them
    apart, so the policy stays the newest, as without a selection."""
    run = _train(tmp_path / "runs", "train.max_iterations=3", "train.select_checkpoint_trials=2", "--no-eval")
    selection = json.loads(run.selection_path.read_text())
    assert selection["scores"] == {"0": 0.0, "1": 0.0, "2": 0.0}
    assert selection["checkpoint"] == "model_2.pt"


def test_an_unreadable_checkpoint_is_left_out_and_a_broken_selection_is_an_error(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    run = _train(tmp_path / "runs", "train.max_iterations=3", "--no-eval")
    assert not run.selection_path.exists()  # off by default: the newest is the policy
    assert run_policy_checkpoint(run.path) == run.checkpoints / "model_2.pt"
    (run.checkpoints / "model_0.pt").write_bytes(b"truncated")
    _scripted_scores(monkeypatch, [0.4, 0.3])
    cfg = run.config()
    cfg = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, select_checkpoint_trials=2))
    line = select_checkpoint(run, cfg, "cpu")
    assert "1: 0.40, 2: 0.30 (unreadable, left out: model_0.pt); the run's policy is model_1.pt" in line, line
    capsys.readouterr()

    run.selection_path.write_text('{"checkpoint": "../../etc/passwd"}')
    assert cli.main(["eval", str(run.path), "--trials", "2"]) == 2
    err = capsys.readouterr().err
    assert "selection.json" in err and "not a checkpoint file name" in err, err
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(tmp_path / "bad"), *TINY,
                     "train.select_checkpoint_trials=-1"]) == 2
    err = capsys.readouterr().err
    assert "train.select_checkpoint_trials" in err, err
    assert not (tmp_path / "bad").exists()


def test_a_later_stage_starts_from_the_policy_its_evaluation_read_when_the_newest_file_is_broken(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    """A disk that filled leaves a truncated newest checkpoint: the run's evaluation falls back
    to the previous file, and `train.init_from` of the next stage must start from that same
    file, not stop on the broken one."""
    source = _train(tmp_path / "runs", "train.max_iterations=2", "--no-eval")
    (source.checkpoints / "model_1.pt").write_bytes(b"truncated")
    assert run_policy_checkpoint(source.path) == source.checkpoints / "model_0.pt"
    assert find_init_checkpoint(str(source.path)) == (source.checkpoints / "model_0.pt", source.path)
    capsys.readouterr()
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(tmp_path / "next"), *TINY,
                     "train.max_iterations=1", "--no-eval", f"train.init_from={source.path}"]) == 0
    said = capsys.readouterr().out
    assert "skipping" in said and "model_1.pt" in said, said
    assert f"initialised from {source.checkpoints / 'model_0.pt'}" in said, said
