"""`train.teachers` (kickstarting): a frozen teacher per skill pulls the student's mean action
toward its own on that skill's steps, beside PPO; through the CLI and the run's log."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach import cli
from detach.config import resolve
from detach.runs.folder import find_runs
from detach.runs.mcap_log import read_metrics
from detach.train.checks import complete_run_config
from detach.train.setup import build_runner

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "eval.trials=2"]
FOLLOW = str(ROOT / "configs/tasks/follow.yaml")


@pytest.fixture(scope="module")
def teacher_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("teacher")
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, "train.max_iterations=1",
                     "--no-eval", "--seed", "3"]) == 0
    (run,) = find_runs(out)
    return run.path


def test_a_student_moves_toward_its_teacher(teacher_run: Path, tmp_path: Path) -> None:
    """Every Follow step is the teacher's skill: the student's mean actions, from a network of
    another seed, come close to the teacher's within a few iterations."""
    out = tmp_path / "runs"
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, "train.max_iterations=8",
                     "--no-eval", f"+train.teachers.follow={teacher_run}", "train.teacher_weight=50",
                     "train.learning_rate=1e-3", "train.schedule=fixed"]) == 0
    (run,) = find_runs(out)
    metrics = read_metrics(run.log_path)
    mse = [m["Loss/teacher/follow/mse"] for m in metrics]
    assert all(m["Loss/teacher/follow/share"] == 1.0 for m in metrics), "every step is Follow's"
    assert max(mse[-2:]) < 0.6 * mse[0], mse


def test_teacher_only_distils_without_a_ppo_update(teacher_run: Path, tmp_path: Path) -> None:
    """`train.teacher_only`: the critic keeps its initial weights (no PPO update), the actor
    still moves toward the teacher."""
    out = tmp_path / "runs"
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, "train.max_iterations=4",
                     "--no-eval", "--seed", "5", f"+train.teachers.follow={teacher_run}", "train.teacher_only=true",
                     "train.learning_rate=1e-3", "train.schedule=fixed", "train.save_interval=1"]) == 0
    (run,) = find_runs(out)
    first, last = (torch.load(run.checkpoints / f"model_{i}.pt", weights_only=True) for i in (1, 3))
    critic = [k for k in first["critic_state_dict"] if "normalizer" not in k]
    assert critic and all(torch.equal(first["critic_state_dict"][k], last["critic_state_dict"][k]) for k in critic)
    mse = [m["Loss/teacher/follow/mse"] for m in read_metrics(run.log_path)]
    assert mse[-1] < 0.6 * mse[0], mse
    assert "Loss/surrogate" not in read_metrics(run.log_path)[-1]


def test_a_skill_without_steps_in_the_batch_adds_nothing(teacher_run: Path) -> None:
    """A Carry teacher in a Follow run: no step is Carry's, so the loss is 0 and moves nothing."""
    cfg = complete_run_config(resolve(FOLLOW, "mlp", TINY + [f"+train.teachers.carry={teacher_run}"]))
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    loss, logs = runner.alg.teacher_loss_fn(env.get_observations())
    assert float(loss.detach()) == 0.0 and logs["teacher/carry/share"] == 0.0
    loss.backward()
    assert all(p.grad is None or not p.grad.any() for p in runner.alg.actor.parameters())


def test_a_policy_teaching_two_skills_is_loaded_once(teacher_run: Path) -> None:
    """Follow and Carry from the same run (the preservation case): one actor, both skills."""
    from detach.train.teachers import load_teachers

    cfg = complete_run_config(resolve(FOLLOW, "mlp", TINY + [f"+train.teachers.follow={teacher_run}",
                                                             f"+train.teachers.carry={teacher_run}"]))
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    teachers = load_teachers(cfg, env, "cpu")
    assert len(teachers.actors) == 1 and teachers.skills == [["follow", "carry"]]
    _loss, logs = runner.alg.teacher_loss_fn(env.get_observations())
    assert logs["teacher/follow/share"] == 1.0 and logs["teacher/carry/share"] == 0.0


@pytest.mark.parametrize("override, expected", [
    ("+train.teachers.flow=RUN", "flow"),
    ("+train.teachers.follow=/nowhere/run", "neither a run folder nor a checkpoint file"),
    ("train.teacher_weight=-1", "teacher_weight"),
    ("train.teacher_only=true", "teacher_only"),
])
def test_bad_teachers_are_one_line_errors(teacher_run: Path, tmp_path: Path, capsys, override: str,
                                          expected: str) -> None:
    out = tmp_path / "runs"
    code = cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, "train.max_iterations=1",
                     override.replace("RUN", str(teacher_run))])
    assert code == 2
    err = capsys.readouterr().err
    assert expected in err and "train.teacher" in err, err
    assert not out.exists() or not any(out.iterdir()), "nothing half-written"
