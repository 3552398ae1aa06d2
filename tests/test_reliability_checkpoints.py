"""Checkpoints through the CLI: never unpickled, fallback past a truncated file, refused when
of another model, pruned by `train.keep_checkpoints`, written whole on a full disk, and a
resumed log that holds every iteration once (docs/RELIABILITY.md).

One tiny run (puppet, follow, MLP) is trained once per module; each test works on a copy.
"""

from __future__ import annotations

import builtins
import errno
import json
import os
import shutil
import stat
from pathlib import Path

import pytest
import torch

from detach import cli
from detach.runfolder.folder import RunFolder, find_runs
from detach.runfolder.mcap_reader import read_metrics
from detach.train import checkpoints as checkpoint_io
from tests.test_runner_cli import FOLLOW, TINY

RUN_ARGS = [FOLLOW, "--model", "mlp", "--no-eval", "train.max_iterations=4", "train.save_interval=1",
            "train.keep_checkpoints.last=2", "train.keep_checkpoints.every=2", *TINY]


UMASK = 0o027
"""The module's run is trained under this umask: group may read, others may not."""


@pytest.fixture(scope="module")
def trained(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("trained")
    previous = os.umask(UMASK)
    try:
        assert cli.main([*RUN_ARGS, "--out", str(out)]) == 0
    finally:
        os.umask(previous)
    (run,) = find_runs(out)
    return run.path


@pytest.fixture()
def run(trained: Path, tmp_path: Path) -> RunFolder:
    copy = tmp_path / trained.name
    shutil.copytree(trained, copy)
    return RunFolder(copy)


def _one_error_line(capsys: pytest.CaptureFixture[str]) -> str:
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1, err
    return err[0]


class CodeOnLoad:
    """Unpickling this creates a file: what a malicious checkpoint could do, harmlessly."""

    def __init__(self, marker: Path) -> None:
        self.marker = marker

    def __reduce__(self):
        return builtins.open, (str(self.marker), "w")


def test_run_files_follow_the_umask(trained: Path) -> None:
    """Not 0600 (tempfile's mode): a dashboard run by another user of the group can read them."""
    modes = {p.relative_to(trained).as_posix(): stat.S_IMODE(p.stat().st_mode) for p in trained.rglob("*")}
    assert {"config.yaml", "status.json", "stdout.log", "log.mcap", "checkpoints/model_3.pt",
            "checkpoints/amp_replay_3.pt"} <= set(modes)
    assert {name: mode for name, mode in modes.items() if mode != (0o750 if (trained / name).is_dir()
                                                                  else 0o640)} == {}


def test_retention_keeps_the_last_and_every_nth(run: RunFolder) -> None:
    # saved 0..3; last=2 keeps 2 and 3, every=2 keeps iterations 1 and 3 (counts 2 and 4)
    assert [p.name for p in run.checkpoint_files()] == ["model_3.pt", "model_2.pt", "model_1.pt"]
    assert checkpoint_io.kept_iterations([0, 1, 2, 3, 4, 5], last=0, every=0) == {0, 1, 2, 3, 4, 5}
    assert checkpoint_io.kept_iterations([9, 49, 99, 149], last=1, every=100) == {99, 149}
    assert checkpoint_io.kept_iterations([7], last=1, every=0) == {7}


def test_a_checkpoint_that_would_run_code_is_refused(run: RunFolder, tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    marker = tmp_path / "code-ran"
    state = torch.load(run.latest_checkpoint(), weights_only=True)
    state["infos"]["payload"] = CodeOnLoad(marker)
    torch.save(state, run.latest_checkpoint())
    capsys.readouterr()
    assert cli.main(["eval", str(run.path), "--trials", "1"]) == 2
    assert "refused" in _one_error_line(capsys) and not marker.exists()
    assert cli.main(["eval", str(run.latest_checkpoint()), "--trials", "1"]) == 2
    assert "refused" in _one_error_line(capsys) and not marker.exists()
    assert cli.main(["resume", str(run.path), "--no-eval"]) == 2
    assert "refused" in _one_error_line(capsys) and not marker.exists()
    assert run.status().state == "finished", "a refused resume leaves the run as it was"
    # as a later stage's start: said as such, with how to get a file that loads (it said
    # "cannot read X (UnpicklingError)")
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(tmp_path / "later"), "env.character=puppet",
                     "sim.num_envs=4", "train.max_iterations=1", f"train.init_from={run.latest_checkpoint()}"]) == 2
    said = _one_error_line(capsys)
    assert "train.init_from" in said and "Python objects" in said and "--format init" in said, said
    assert not marker.exists()
    capsys.readouterr()
    assert cli.main(["list", "--runs", str(tmp_path / "later")]) == 0  # the failed run says why it failed
    listed = capsys.readouterr().out
    assert " failed " in listed and "failed: train.init_from" in listed and "Python objects" in listed, listed


def test_a_truncated_checkpoint_falls_back_and_the_log_keeps_each_iteration_once(
        run: RunFolder, capsys: pytest.CaptureFixture[str]) -> None:
    newest = run.latest_checkpoint()
    newest.write_bytes(newest.read_bytes()[: newest.stat().st_size // 2])
    (run.checkpoints / ".model_7.pt.999999999.0bad.tmp").write_bytes(b"half")  # a killed writer's
    (run.checkpoints / "model_5.pt.tmp").write_bytes(b"half")  # the older naming
    assert cli.main(["--resume", str(run.path), "--dry-run"]) == 0
    assert "# would resume" in capsys.readouterr().out and newest.exists()
    assert cli.main(["--resume", str(run.path), "--no-eval"]) == 0
    out = capsys.readouterr().out
    assert "skipping" in out and "model_3.pt" in out and "from model_2.pt" in out
    assert (run.checkpoints / "model_3.pt.corrupt").exists()
    assert run.status().state == "finished"
    assert [m["iteration"] for m in read_metrics(run.log_path)] == [0, 1, 2, 3], \
        "iteration 3 was trained again: the log holds it once"
    assert not [p for p in run.checkpoints.iterdir() if p.name.endswith(".tmp")]
    assert checkpoint_io.read_checkpoint(run.latest_checkpoint())["iter"] == 3


def test_evaluation_falls_back_past_a_truncated_checkpoint(run: RunFolder,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    for path in run.checkpoint_files()[:2]:
        path.write_bytes(b"PK\x03\x04 cut short")
    assert cli.main(["--eval", str(run.path), "--trials", "1"]) == 0
    assert "skipping" in capsys.readouterr().out
    assert run.eval_result().checkpoint == "checkpoints/model_1.pt"
    run.checkpoint_files()[-1].write_bytes(b"")
    assert cli.main(["eval", str(run.path), "--trials", "1"]) == 2
    assert "no readable checkpoint" in _one_error_line(capsys)


def test_a_checkpoint_of_another_model_is_one_line(run: RunFolder,
                                                   capsys: pytest.CaptureFixture[str]) -> None:
    path = run.latest_checkpoint()
    state = torch.load(path, weights_only=True)
    state["infos"].update(model="tokenhsi", model_kind="tokenhsi")
    torch.save(state, path)
    capsys.readouterr()
    assert cli.main(["eval", str(run.path), "--trials", "1"]) == 2
    assert "checkpoint is for model tokenhsi (tokenhsi), the run is mlp (mlp)" in _one_error_line(capsys)
    assert cli.main(["resume", str(run.path)]) == 2
    assert "checkpoint is for model tokenhsi" in _one_error_line(capsys)
    # a file that does not say its model: the weights themselves do not fit
    state["infos"] = {}
    state["actor_state_dict"] = {"encoder.weight": torch.zeros(3, 3)}
    torch.save(state, path)
    assert cli.main(["eval", str(path), "--trials", "1"]) == 2
    line = _one_error_line(capsys)
    assert "weights do not fit this run's model" in line and "unexpected (e.g. encoder.weight)" in line


def test_a_full_disk_fails_the_run_in_one_line_and_leaves_no_partial_file(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    real_save = torch.save

    def save_until_the_disk_is_full(obj, f, *args, **kwargs):
        if ".model_2.pt." in f.name:  # the third checkpoint: a part written, then ENOSPC
            f.write(b"\0" * 4096)
            raise OSError(errno.ENOSPC, "No space left on device")
        return real_save(obj, f, *args, **kwargs)

    monkeypatch.setattr(checkpoint_io.torch, "save", save_until_the_disk_is_full)
    code = cli.main(["train", *RUN_ARGS, "--out", str(tmp_path)])
    err = capsys.readouterr().err
    (run,) = find_runs(tmp_path)
    assert code == 1 and "Traceback" not in err
    assert [line for line in err.splitlines() if line.startswith("detach-run")] == [
        f"detach-run: run failed: No space left on device ({run.path})"]
    status = run.status()
    assert status.state == "failed" and status.error == "No space left on device"
    # model_2's temporary file and its replay sidecar are gone; retention kept 0 and 1
    assert [p.name for p in sorted(run.checkpoints.iterdir())] == ["amp_replay_1.pt", "model_0.pt",
                                                                  "model_1.pt"]
    assert checkpoint_io.read_checkpoint(run.checkpoints / "model_1.pt")["iter"] == 1
    assert "Traceback" in run.stdout_path.read_text(), "the details stay in stdout.log"


def test_status_is_recorded_even_when_no_new_file_fits(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    from detach.config import resolve
    from detach.runfolder import atomic

    run = RunFolder.create(tmp_path, resolve(FOLLOW, "mlp"))
    run.set_state("running", iteration=7)

    def disk_full(*_a, **_k):
        raise OSError(errno.ENOSPC, "No space left on device")

    monkeypatch.setattr(atomic, "atomic_writer", disk_full)
    run.set_state("failed", error="No space left on device")
    assert run.status().state == "failed" and run.status().iteration == 7
    assert json.loads(run.status_path.read_text())["error"] == "No space left on device"


def test_a_run_says_when_the_disk_is_about_to_fill_before_a_save_fails(
        tmp_path: Path, monkeypatch: pytest.MonkeyPatch, capsys: pytest.CaptureFixture[str]) -> None:
    """A runs folder that grew to fill the disk stopped a run mid-write with no word before:
    now each save checks the room left and says so, once, while there is time to act."""
    usage = shutil.disk_usage(tmp_path)
    free = {"bytes": 100 * 2**30}
    monkeypatch.setattr(checkpoint_io.shutil, "disk_usage", lambda _path: usage._replace(free=free["bytes"]))
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(tmp_path / "ok"), *TINY,
                     "train.max_iterations=3", "train.save_interval=1", "--no-eval"]) == 0
    assert "room for about" not in capsys.readouterr().out  # 100 GiB free: room enough

    free["bytes"] = 200 * 2**20  # 200 MB: a few saves of the tiny run (~60 MB each) fit
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(tmp_path / "low"), *TINY,
                     "train.max_iterations=4", "train.save_interval=1", "--no-eval"]) == 0
    said = capsys.readouterr().out
    warnings = [line for line in said.splitlines() if "room for about" in line]
    assert len(warnings) == 1, said  # once, not at every save
    assert warnings[0].startswith("warning: 0.2 GiB free on the disk of ") and "train.keep_checkpoints" in warnings[0]
    # kept to the last two checkpoints, the folder stops growing: a save needs only its own room
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(tmp_path / "kept"), *TINY,
                     "train.max_iterations=4", "train.save_interval=1", "train.keep_checkpoints.last=2",
                     "--no-eval"]) == 0
    said = capsys.readouterr().out
    assert sum("room for about" in line for line in said.splitlines()) == 1, said  # the first saves grow it
