"""Resuming never changes the past: a longer run extends its last stage instead of rescaling
DETACH's schedule, and a stated schedule must keep every completed iteration's stage
(docs/RELIABILITY.md). Runs here are folders with a stand-in checkpoint: nothing trains."""

from __future__ import annotations

import json
import re
import subprocess
from pathlib import Path

import pytest
import torch
import yaml

from detach import cli
from detach.config import resolve
from detach.config.schema import StagesCfg
from detach.runfolder.folder import RunFolder
from detach.runs.provenance import code_change_since, git_state
from detach.train.schedule import extend_schedule, stage_at, stage_lengths
from tests.test_runner_cli import FOLLOW


@pytest.fixture()
def detach_run(tmp_path: Path) -> RunFolder:
    """A DETACH run of 20 iterations (paper stages 100/400/500 scaled: 2 + 8 + 10), stopped
    after iteration 14, in its joint stage."""
    cfg = resolve(FOLLOW, "detach", ["train.max_iterations=20", "env.character=puppet"])
    assert stage_lengths(cfg.train.stages, 20) == [("pretrain", 2), ("fusion", 8), ("joint", 10)]
    run = RunFolder.create(tmp_path, cfg)
    torch.save({"actor_state_dict": {}, "critic_state_dict": {}, "iter": 14,
                "infos": {"stage": "joint", "model": "detach", "model_kind": "detach"}},
               run.checkpoints / "model_14.pt")
    run.set_state("interrupted", iteration=15)
    return run


def _stages_printed(capsys: pytest.CaptureFixture[str]) -> dict[str, int]:
    return yaml.safe_load(capsys.readouterr().out)["train"]["stages"]


def test_training_longer_extends_the_last_stage(detach_run: RunFolder, monkeypatch: pytest.MonkeyPatch,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--resume", str(detach_run.path), "train.max_iterations=40", "--dry-run"]) == 0
    assert _stages_printed(capsys) == {"pretrain": 2, "fusion": 8, "joint": 30}
    trained = []
    monkeypatch.setattr("detach.runs.session.train_and_evaluate", lambda _run, cfg, **_k: trained.append(cfg))
    assert cli.main(["--resume", str(detach_run.path), "train.max_iterations=40"]) == 0
    cfg = detach_run.config()
    assert cfg.train.max_iterations == 40 and cfg.train.stages == StagesCfg(2, 8, 30)
    assert trained == [cfg], "the session trains the config it wrote, from memory"
    assert stage_lengths(cfg.train.stages, 40) == [("pretrain", 2), ("fusion", 8), ("joint", 30)]
    assert cli.main(["--resume", str(detach_run.path), "train.max_iterations=50"]) == 0
    assert detach_run.config().train.stages == StagesCfg(2, 8, 40)


def test_a_stated_schedule_may_not_change_completed_iterations(detach_run: RunFolder,
                                                               capsys: pytest.CaptureFixture[str]) -> None:
    argv = ["resume", str(detach_run.path), "train.max_iterations=40", "--dry-run"]
    assert cli.main([*argv, "train.stages.pretrain=2", "train.stages.fusion=20", "train.stages.joint=18"]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "puts iteration 10 in 'fusion', but the run trained it in 'joint'" in err[0]
    assert cli.main([*argv, "train.stages.pretrain=2", "train.stages.fusion=8", "train.stages.joint=30"]) == 0
    assert _stages_printed(capsys) == {"pretrain": 2, "fusion": 8, "joint": 30}
    assert detach_run.config().train.stages == StagesCfg(100, 400, 500), "a dry run writes nothing"


def test_a_run_cannot_be_resumed_into_fewer_iterations_than_it_did(detach_run: RunFolder,
                                                                  capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(["--resume", str(detach_run.path), "train.max_iterations=10"]) == 2
    assert "expected more than the 15 iterations the run has completed, found 10" in capsys.readouterr().err


def test_extending_a_schedule_keeps_the_stage_of_every_earlier_iteration() -> None:
    before = [("pretrain", 2), ("fusion", 8), ("joint", 10)]
    for total in (20, 21, 40, 1000):
        after = extend_schedule(before, total)
        assert sum(k for _n, k in after) == total
        assert all(stage_at(after, i) == stage_at(before, i) for i in range(20))
    assert extend_schedule(before, 5) == [("pretrain", 2), ("fusion", 3)]


def _trained_with(run: RunFolder, git: dict | None) -> None:
    (run.path / "provenance.json").write_text(json.dumps({"runs": [{"resumed": False, "git": git}]}))


def test_resuming_under_other_code_says_so(detach_run: RunFolder, monkeypatch: pytest.MonkeyPatch,
                                           capsys: pytest.CaptureFixture[str]) -> None:
    """A sweep resumes an interrupted cell by its config digest; the code may have changed since
    (stop 26: Carry runs interrupted before a reward fix resumed under the fix, unannounced)."""
    now = git_state()
    if now is None or not now.get("commit"):
        pytest.skip("the source tree is not a git work tree")
    monkeypatch.setattr("detach.runs.session.train_and_evaluate", lambda *_a, **_k: None)
    _trained_with(detach_run, {**now, "commit": "f" * 40, "diff": ""})
    assert cli.main(["--resume", str(detach_run.path)]) == 0
    out = capsys.readouterr().out
    assert f"last trained with code at commit ffffffffff; it resumes with {now['commit'][:10]}" in out
    assert "The iterations from here run under the new code." in out
    _trained_with(detach_run, now)
    assert cli.main(["--resume", str(detach_run.path)]) == 0
    assert "warning" not in capsys.readouterr().out


def test_the_code_change_warning_names_the_changed_files(detach_run: RunFolder) -> None:
    now = git_state()
    if now is None or not now.get("commit"):
        pytest.skip("the source tree is not a git work tree")
    first = subprocess.run(["git", "rev-list", "--max-parents=0", "HEAD"], cwd=now["root"],
                           capture_output=True, text=True).stdout.split()
    if not first or first[0] == now["commit"]:
        pytest.skip("a shallow clone: no earlier commit to compare with")
    _trained_with(detach_run, {**now, "commit": first[0], "diff": ""})
    warning = code_change_since(detach_run, {**now, "diff": ""})
    assert warning is not None
    count = re.search(r"(\d+) code file\(s\) differ: ", warning)
    assert count is not None and int(count.group(1)) > 10  # the whole package, from the first commit
    _trained_with(detach_run, None)  # trained outside a git work tree: nothing to compare
    assert code_change_since(detach_run, now) is None
    _trained_with(detach_run, {**now, "diff": "+x\n"})
    warning = code_change_since(detach_run, {**now, "diff": ""})
    assert warning is not None and f"at commit {now['commit'][:10]} (uncommitted changes); it resumes" in warning


def test_resuming_may_change_the_number_of_torch_threads(detach_run: RunFolder, monkeypatch: pytest.MonkeyPatch,
                                                         capsys: pytest.CaptureFixture[str]) -> None:
    """A run started on a laptop may go on where there are more cores (or fewer, beside
    another run): the thread count changes speed, not the numbers a checkpoint holds."""
    monkeypatch.setattr("detach.runs.session.train_and_evaluate", lambda *_a, **_k: None)
    assert cli.main(["--resume", str(detach_run.path), "train.torch_threads=1"]) == 0, capsys.readouterr().err
    cfg = detach_run.config()
    assert cfg.train.torch_threads == 1 and cfg.train.max_iterations == 20
    assert cfg.train.stages == StagesCfg(2, 8, 10), "the schedule is the run's own"
    assert cli.main(["--resume", str(detach_run.path), "train.learning_rate=1.0e-3"]) == 2
    assert "cannot change 'train.learning_rate' when resuming" in capsys.readouterr().err
