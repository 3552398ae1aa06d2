"""`clone_clip_start`: the actor fitted to the clips' open-loop hinge targets, written as a
checkpoint that `train.init_from` starts a humanoid run from."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach import build_runner, cli, clone_clip_start, load_initial_weights, resolve
from detach.eval.aids import run_aids
from detach.runfolder.folder import find_runs

ROOT = Path(__file__).resolve().parents[1]
SMALL = ["env.init=random", "sim.num_envs=8", "env.height_map.enabled=false", "train.max_iterations=1",
         "model.learn_noise_std=false", "model.init_noise_std=0.055"]


def test_the_clone_fits_the_clips_and_starts_a_run(tmp_path: Path) -> None:
    torch.set_num_threads(1)
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", SMALL)
    out = tmp_path / "clone.pt"
    lines: list[str] = []
    figures = clone_clip_start(cfg, out, rounds=2, steps=8, epochs=40, assist=(1000.0, 30.0), log=lines.append)
    assert out.is_file() and any(line.startswith("closed loop, assist 1000/30") for line in lines)
    assert 50 < figures["pairs"] <= 2 * 8 * 8
    assert figures["mse"] < 0.5 * figures["action_variance"], figures  # it learned the targets
    start = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", [*SMALL[1:], f"train.init_from={out}"])
    _env, runner = build_runner(start, None, "cpu", progress=False)
    assert "initialised from" in load_initial_weights(runner, start)


def test_a_run_from_scratch_with_clone_start_trains_from_its_clone_and_names_the_aid(tmp_path: Path) -> None:
    out = tmp_path / "runs"
    clone = ["train.clone_start.rounds=2", "train.clone_start.steps=8", "train.clone_start.epochs=5"]
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(out), "--no-eval", *SMALL[1:], *clone,
                     "train.torch_threads=1"]) == 0  # env.init stays mixed: the clone draws its own starts
    (run,) = find_runs(out)
    log = run.stdout_path.read_text()
    assert (run.path / "clone_start.pt").is_file() and "closed loop, assist 0/0" in log
    assert f"initialised from {run.path / 'clone_start.pt'} (model mlp (mlp)" in log
    assert run.config().env.init == "mixed" and run_aids(run.config()) == ["cloned start"]


@pytest.mark.parametrize("extra, expected", [
    (["env.character=puppet"], "acts on more than its 32 hinges"),
    (["train.init_from=runs/elsewhere"], "train.init_from gives it one"),
])
def test_a_clone_start_where_it_cannot_apply_is_one_line(tmp_path: Path, capsys: pytest.CaptureFixture[str],
                                                          extra: list[str], expected: str) -> None:
    assert cli.main(["train", "follow", "--model", "mlp", "--runs", str(tmp_path), "--dry-run",
                     "train.clone_start.rounds=2", *extra]) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and "train.clone_start.rounds" in err[0] and expected in err[0], err
