"""detach-run end to end: run folders and their states, resume, evaluation, sweeps, tables.

Runs use the puppet on the follow task with tiny settings so each takes seconds on CPU.
"""

from __future__ import annotations

import json
import signal
import subprocess
import sys
import time
from pathlib import Path

import pytest
import torch

from detach import cli
from detach.runfolder.eval_result import EvalResult
from detach.runfolder.folder import RunFolder, find_runs
from detach.runfolder.mcap_reader import read_episodes, read_metrics, read_scene

ROOT = Path(__file__).resolve().parents[1]
FOLLOW = str(ROOT / "configs/tasks/follow.yaml")
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8",
        "eval.num_envs=2", "env.episode_length=60"]


def _only_run(out: Path) -> RunFolder:
    runs = find_runs(out)
    assert len(runs) == 1, runs
    return runs[0]


def test_finished_run_leaves_the_contracted_files(tmp_path: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    reads: list[Path] = []
    read = RunFolder.config
    monkeypatch.setattr(RunFolder, "config", lambda self: reads.append(self.path) or read(self))
    code = cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--trials", "2",
                     "train.max_iterations=2", *TINY])
    assert code == 0
    assert reads == [], "trained and evaluated from the config in memory: config.yaml is not read back"
    run = _only_run(tmp_path)
    assert run.path.name.endswith("-follow-mlp-s0")
    status = run.status()
    assert status.state == "finished" and status.iteration == 2 and status.error is None
    assert run.config().env.character == "puppet"
    assert (run.checkpoints / "model_1.pt").exists()
    assert "evaluation on follow" in run.stdout_path.read_text()
    metrics = read_metrics(run.log_path)
    assert [m["iteration"] for m in metrics] == [0, 1] and metrics[0]["Perf/total_fps"] > 0
    scene = read_scene(run.log_path)
    assert len(scene.bodies) == 15 and scene.body_geoms
    assert [t.skill for t in scene.targets] == [] and scene.objects == []  # traj_rand: nothing to draw
    frames = read_episodes(run.log_path)[1]  # recorded under the checkpoint's iteration
    assert len(frames) >= 2 and len(frames[0]["pos"]) == 15
    result = run.eval_result()
    assert result.trials == 2 and result.task == result.trained_on == "follow"
    assert result.plan == ["follow"] and 0.0 <= result.lh_success.rate <= 1.0


def test_crash_marks_the_run_failed(tmp_path: Path, monkeypatch: pytest.MonkeyPatch,
                                    capsys: pytest.CaptureFixture[str]) -> None:
    import detach.runs.session as session

    def broken(*_a, **_k):
        raise RuntimeError("injected failure")

    monkeypatch.setattr(session, "build_runner", broken)
    code = cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), *TINY])
    assert code == 1
    run = _only_run(tmp_path)
    assert run.status().state == "failed"
    assert run.status().error == "RuntimeError: injected failure"
    assert "injected failure" in run.stdout_path.read_text()
    assert "run failed: RuntimeError: injected failure" in capsys.readouterr().err


def test_sigterm_interrupts_then_resume_finishes(tmp_path: Path) -> None:
    cmd = [sys.executable, "-m", "detach.cli", FOLLOW, "--model", "mlp", "--out",
           str(tmp_path), "--no-eval", "train.max_iterations=200", *TINY]
    proc = subprocess.Popen(cmd, stdout=subprocess.DEVNULL, stderr=subprocess.DEVNULL,
                            cwd=ROOT)
    deadline = time.time() + 120
    run = None
    while time.time() < deadline:
        runs = find_runs(tmp_path)
        if runs:
            run = runs[0]
            try:
                if run.status().iteration >= 2:
                    break
            except (OSError, ValueError):
                pass
        time.sleep(0.2)
    assert run is not None, "run folder never appeared"
    proc.send_signal(signal.SIGTERM)
    assert proc.wait(timeout=60) == 130
    status = run.status()
    assert status.state == "interrupted" and "SIGTERM" in status.error
    checkpoint = run.latest_checkpoint()
    done = int(checkpoint.stem.split("_")[1])
    assert done + 1 == status.iteration, "the checkpoint is the last completed iteration"
    code = cli.main(["--resume", str(run.path), "--no-eval", f"train.max_iterations={done + 3}"])
    assert code == 0 and run.status().state == "finished"
    iterations = [m["iteration"] for m in read_metrics(run.log_path)]
    assert iterations == list(range(done + 3)), "the log keeps the first part and continues"


def test_resume_refuses_changes_that_break_checkpoints(tmp_path: Path,
                                                       capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--no-eval",
                     "train.max_iterations=1", *TINY]) == 0
    run = _only_run(tmp_path)
    assert cli.main(["--resume", str(run.path), "model.adapter_units=[8]"]) == 2
    assert "cannot change 'model.adapter_units' when resuming" in capsys.readouterr().err


def test_eval_on_another_task_writes_its_own_file(tmp_path: Path) -> None:
    assert cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--no-eval",
                     "train.max_iterations=1", *TINY]) == 0
    run = _only_run(tmp_path)
    sit = ROOT / "configs/tasks/sit.yaml"
    assert cli.main(["--eval", str(run.path), "--task", str(sit), "--trials", "2"]) == 0
    result = EvalResult.from_json(json.loads((run.path / "eval_sit.json").read_text()))
    assert result.task == "sit" and result.trained_on == "follow"
    assert result.plan == ["sit"] and not run.eval_path.exists()


def test_evaluation_uses_the_runs_torch_threads(tmp_path: Path) -> None:
    # `detach-run eval` ran with torch's default threads whatever train.torch_threads said: two
    # evaluations side by side on 2 cores then fought MuJoCo's threads and ran 8x slower
    before = torch.get_num_threads()
    try:
        assert cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--no-eval",
                         "train.max_iterations=1", "train.torch_threads=1", *TINY]) == 0
        torch.set_num_threads(2)  # what a fresh process on 2 cores has
        assert cli.main(["eval", str(_only_run(tmp_path).path), "--trials", "2"]) == 0
        assert torch.get_num_threads() == 1
    finally:
        torch.set_num_threads(before)


def test_a_smaller_evaluation_does_not_replace_a_larger_one_unless_asked(
        tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    # a 4-trial check once silently replaced a committed 100-trial eval.json
    assert cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--trials", "3",
                     "train.max_iterations=1", *TINY]) == 0
    run = _only_run(tmp_path)
    before = run.eval_path.read_bytes()
    capsys.readouterr()
    assert cli.main(["eval", str(run.path), "--trials", "2"]) == 2
    err = capsys.readouterr().err
    assert "holds a 3-trial evaluation" in err and "--replace" in err
    assert run.eval_path.read_bytes() == before
    assert cli.main(["eval", str(run.path), "--trials", "2", "--replace"]) == 0
    assert EvalResult.from_json(json.loads(run.eval_path.read_text())).trials == 2
    assert cli.main(["eval", str(run.path), "--trials", "2"]) == 0  # as many trials: a re-evaluation


def test_list_shows_runs_and_unreadable_folders(tmp_path: Path,
                                                capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--no-eval",
                     "train.max_iterations=1", *TINY]) == 0
    broken = tmp_path / "20260101-000000-lh1-mlp-s0"
    broken.mkdir()
    (broken / "status.json").write_text("{not json")
    capsys.readouterr()
    assert cli.main(["list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    rows = [line.split() for line in out.splitlines()]
    assert any(r[1:6] == ["follow", "mlp", "0", "finished", "1"] for r in rows if len(r) >= 6)
    assert "unreadable" in out and "20260101-000000-lh1-mlp-s0:" in out


@pytest.mark.parametrize("argv,message", [
    (["resume", "/nonexistent/run"], "not a run folder"),
    (["eval", "/nonexistent/run"], "run folder or checkpoint not found"),
    (["table", "/nonexistent/sweep.yaml"], "sweep file or runs folder not found"),
    ([], "missing TASK"),
])
def test_bad_invocations_are_one_line_errors(argv: list[str], message: str,
                                             capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main(argv) == 2
    err = capsys.readouterr().err.strip().splitlines()
    assert len(err) == 1 and message in err[0]


def test_resume_refuses_a_run_whose_process_is_alive(tmp_path: Path,
                                                     capsys: pytest.CaptureFixture[str]) -> None:
    assert cli.main([FOLLOW, "--model", "mlp", "--out", str(tmp_path), "--no-eval",
                     "train.max_iterations=1", *TINY]) == 0
    run = _only_run(tmp_path)
    sleeper = subprocess.Popen([sys.executable, "-c", "import time; time.sleep(30)"])
    try:
        run.set_state("running")  # records this test's pid; point it at the live sleeper
        status = json.loads(run.status_path.read_text())
        status["pid"] = sleeper.pid
        run.status_path.write_text(json.dumps(status))
        assert cli.main(["--resume", str(run.path)]) == 2
        assert f"run is still running (pid {sleeper.pid})" in capsys.readouterr().err
    finally:
        sleeper.kill()
        sleeper.wait()
    assert cli.main(["--resume", str(run.path), "--no-eval"]) == 0, "a dead pid is stale"
