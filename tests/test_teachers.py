"""`train.teachers` (kickstarting): a frozen teacher per skill pulls the student's mean action
toward its own on that skill's steps, beside PPO; through the CLI and the run's log."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach import cli
from detach.runfolder.folder import find_runs
from detach.runfolder.mcap_reader import read_metrics
from detach.train.run_config import complete_run_config, resolve_run
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
    cfg = resolve_run(FOLLOW, "mlp", TINY + [f"+train.teachers.carry={teacher_run}"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    loss, logs = runner.alg.policy_loss_fn(env.get_observations())
    assert float(loss.detach()) == 0.0 and logs["teacher/carry/share"] == 0.0
    loss.backward()
    assert all(p.grad is None or not p.grad.any() for p in runner.alg.actor.parameters())


def test_a_policy_teaching_two_skills_is_loaded_once(teacher_run: Path) -> None:
    """Follow and Carry from the same run (the preservation case): one actor, both skills."""
    from detach.train.teachers import load_teachers

    cfg = resolve_run(FOLLOW, "mlp", TINY + [f"+train.teachers.follow={teacher_run}",
                                                             f"+train.teachers.carry={teacher_run}"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    teachers = load_teachers(cfg, env, "cpu")
    assert len(teachers.actors) == 1 and teachers.skills == [["follow", "carry"]]
    _loss, logs = runner.alg.policy_loss_fn(env.get_observations())
    assert logs["teacher/follow/share"] == 1.0 and logs["teacher/carry/share"] == 0.0


def test_the_oracle_teaches_on_the_students_states(tmp_path: Path) -> None:
    """`oracle`: the env stores the scripted oracle's action of every state as the group
    `oracle` of the rollout, and distilling it alone brings a fresh student toward it."""
    out = tmp_path / "runs"
    assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, "train.max_iterations=6",
                     "--no-eval", "+train.teachers.follow=oracle", "train.teacher_only=true",
                     "train.learning_rate=1e-3", "train.schedule=fixed"]) == 0
    (run,) = find_runs(out)
    mse = [m["Loss/teacher/follow/mse"] for m in read_metrics(run.log_path)]
    assert mse[-1] < 0.6 * mse[0], mse


def test_the_oracle_group_is_the_oracles_action_in_the_state_observed() -> None:
    from detach.envs.oracle import ORACLE_GROUP, Oracle

    cfg = resolve_run(FOLLOW, "mlp", TINY + ["+train.teachers.follow=oracle"])
    env, _runner = build_runner(cfg, None, "cpu", progress=False)
    gen = torch.Generator().manual_seed(0)
    for _ in range(3):
        obs, *_ = env.step(torch.rand(env.num_envs, env.num_actions, generator=gen) * 2 - 1)
    expected = Oracle(env)()
    assert obs[ORACLE_GROUP].shape == (env.num_envs, env.num_actions)
    assert torch.equal(obs[ORACLE_GROUP], expected)
    assert expected.abs().sum() > 0


@pytest.mark.parametrize("override, expected", [
    ("+train.teachers.follow=oracle env.character=humanoid", "root servos"),
    ("+train.teachers.flow=RUN", "flow"),
    ("+train.teachers.follow=/nowhere/run", "neither a run folder nor a checkpoint file"),
    ("train.teacher_weight=-1", "teacher_weight"),
    ("train.teacher_only=true", "teacher_only"),
])
def test_bad_teachers_are_one_line_errors(teacher_run: Path, tmp_path: Path, capsys, override: str,
                                          expected: str) -> None:
    out = tmp_path / "runs"
    code = cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, "train.max_iterations=1",
                     *override.replace("RUN", str(teacher_run)).split()])
    assert code == 2
    err = capsys.readouterr().err
    assert expected in err and "train.teacher" in err, err
    assert not out.exists() or not any(out.iterdir()), "nothing half-written"


def test_action_bound_loss_is_zero_inside_and_grows_beyond() -> None:
    from detach.train.action_bounds import SOFT_BOUND, action_bound_loss

    inside = torch.full((4, 3), SOFT_BOUND - 0.01)
    assert float(action_bound_loss(inside, 10.0)[0]) == 0.0
    mu = torch.tensor([[SOFT_BOUND + 1.0, 0.0, -SOFT_BOUND - 2.0]], requires_grad=True)
    loss, logs = action_bound_loss(mu, 10.0)
    assert float(loss.detach()) == pytest.approx(10.0 * (1.0 + 4.0))
    assert logs["action_bound/beyond"] == pytest.approx(2 / 3)
    loss.backward()
    assert mu.grad[0, 0] > 0 and mu.grad[0, 1] == 0 and mu.grad[0, 2] < 0  # a step pulls both back inside


def test_a_policy_pinned_beyond_an_action_bound_is_pulled_back() -> None:
    """A policy whose mean pelvis-height action sits at 5 (every sample clipped to 1: no signal
    for PPO): `train.action_bound_coef` adds a loss to the update that brings the mean back
    within the bound on the rollout's states."""
    from detach.character.puppet import NUM_ACTIONS

    cfg = resolve_run(FOLLOW, "mlp", TINY + ["train.action_bound_coef=10", "train.learning_rate=1e-3"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    alg = runner.alg
    bias = [p for name, p in alg.actor.named_parameters() if name.endswith("bias") and p.shape == (NUM_ACTIONS,)][-1]
    with torch.no_grad():
        bias[35] = 5.0
    obs = env.get_observations()
    with torch.no_grad():
        before = float(alg.actor(obs)[:, 35].mean())
        first = alg.policy_loss_fn(obs)[0]
    logs = alg._minimise(alg.policy_loss_fn, obs.repeat(16), 20)
    with torch.no_grad():
        after = float(alg.actor(obs)[:, 35].mean())
        last = alg.policy_loss_fn(obs)[0]
    assert before > 4.5 and after < 2.0 and float(last) < 0.1 * float(first), (before, after)
    assert set(logs) == {"action_bound/loss", "action_bound/beyond"}


def test_the_action_bound_loss_is_logged_only_when_asked(tmp_path: Path) -> None:
    for coef in (10.0, 0.0):
        out = tmp_path / f"runs_{coef}"
        assert cli.main(["train", FOLLOW, "--model", "mlp", "--runs", str(out), *TINY, "train.max_iterations=2",
                         "--no-eval", f"train.action_bound_coef={coef}"]) == 0
        (run,) = find_runs(out)
        logged = read_metrics(run.log_path)[-1]
        assert ("Loss/action_bound/loss" in logged) == (coef > 0), sorted(logged)


def test_a_teacher_is_recorded_as_the_checkpoint_it_resolved_to(teacher_run: Path, tmp_path: Path,
                                                                monkeypatch: pytest.MonkeyPatch) -> None:
    """A teacher given as a run folder relative to the shell's directory is written to the
    student's config.yaml as the absolute checkpoint file it meant then: a resume from another
    directory finds it, and one after the teacher's run trained on still learns from the same
    teacher (before, config.yaml held the text as given, and a resume chose the teacher's
    newest checkpoint anew)."""
    monkeypatch.chdir(teacher_run.parent)
    cfg = resolve_run(FOLLOW, "mlp", TINY + [f"+train.teachers.follow={teacher_run.name}",
                                                             "+train.teachers.sit=oracle"])
    recorded = Path(cfg.train.teachers["follow"])
    assert recorded.is_absolute() and recorded == (teacher_run / "checkpoints" / "model_0.pt").resolve()
    assert cfg.train.teachers["sit"] == "oracle"
    assert complete_run_config(cfg).train.teachers == cfg.train.teachers, "completing twice changes nothing"
