"""`train.init_from` across tasks (the progressive protocol) and the observation normalisers.

The bug this guards: Carry started from a Follow run kept Follow's statistics, in which the
box's inputs and the height map had variance 0, so rsl-rl's normaliser divided them by its
eps (0.01) and the policy saw the box 100x too large; with Follow's sample count outweighing
Carry's, it stayed so for hundreds of iterations and Carry learned nothing.
"""

from __future__ import annotations

import warnings
from pathlib import Path
from types import SimpleNamespace

import pytest
import torch

from detach import cli
from detach.character.body import DOF_NAMES
from detach.runfolder.folder import find_runs
from detach.train.run_config import resolve_run
from detach.train.setup import build_runner, load_initial_weights

ROOT = Path(__file__).resolve().parents[1]
TINY = ["env.character=puppet", "sim.num_envs=4", "train.num_steps_per_env=8", "eval.num_envs=2",
        "env.episode_length=60", "eval.trials=2"]


@pytest.fixture(scope="module")
def follow_run(tmp_path_factory: pytest.TempPathFactory) -> Path:
    out = tmp_path_factory.mktemp("runs")
    assert cli.main(["train", str(ROOT / "configs/tasks/follow.yaml"), "--model", "mlp", "--runs", str(out),
                     *TINY, "train.max_iterations=2"]) == 0
    (run,) = find_runs(out)
    return run.path


def _carry_inputs_after_init(follow_run: Path, model: str, policy: str) -> tuple[torch.Tensor, object]:
    """|normalised observation| of a fresh Carry env's first step, as the policy started
    from `follow_run` sees it, and the actor."""
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", model,
                      TINY + [f"train.init_from={follow_run}", f"train.init_normalizers={policy}"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    print(load_initial_weights(runner, cfg))
    actor = runner.alg.actor
    obs = env.get_observations()
    flat = torch.cat([obs[g] for g in actor.obs_groups], dim=-1)
    return actor.obs_normalizer(flat).abs(), actor


def test_kept_statistics_blow_up_the_inputs_follow_never_varied(follow_run: Path) -> None:
    z, _ = _carry_inputs_after_init(follow_run, "mlp", "keep")
    assert z.max() > 50.0  # the failure: inputs Follow never varied scaled by 1/eps


def test_restarted_statistics_take_the_new_task_whole_on_the_first_update(follow_run: Path) -> None:
    z, actor = _carry_inputs_after_init(follow_run, "mlp", "restart")
    assert int(actor.obs_normalizer.count) == 0
    assert z.max() < 50.0
    obs = torch.randn(64, actor.obs_normalizer._mean.shape[-1]) * 3.0 + 2.0
    actor.obs_normalizer.train()
    actor.obs_normalizer.update(obs)
    torch.testing.assert_close(actor.obs_normalizer._mean[0], obs.mean(0))


def test_a_carry_stage_started_from_follow_trains_on_its_own_statistics(follow_run: Path, tmp_path: Path) -> None:
    """Through the CLI (`restart`): the Carry run's checkpoint holds statistics of Carry samples alone."""
    out = tmp_path / "runs"
    assert cli.main(["train", str(ROOT / "configs/tasks/carry.yaml"), "--model", "mlp", "--runs", str(out),
                     *TINY, "train.max_iterations=1", "train.save_interval=1",
                     f"train.init_from={follow_run}", "train.init_normalizers=restart"]) == 0
    (run,) = find_runs(out)
    state = torch.load(sorted(run.checkpoints.glob("model_*.pt"))[-1], weights_only=True)
    source = torch.load(sorted((follow_run / "checkpoints").glob("model_*.pt"))[-1], weights_only=True)
    carry_count = int(state["actor_state_dict"]["obs_normalizer.count"])
    assert 0 < carry_count < int(source["actor_state_dict"]["obs_normalizer.count"]) + 1
    assert carry_count <= 4 * 8  # one iteration of 4 envs x 8 steps: Follow's samples are gone


def test_a_frozen_base_policy_keeps_its_statistics_and_holds_unseen_inputs_at_their_value(
        tmp_path_factory: pytest.TempPathFactory) -> None:
    """CML's cooperative policy on its frozen meta policy: the meta policy's normaliser is not
    restarted (it is never updated), and an input Follow never varied normalises to ~0, the
    value the frozen network saw, instead of (x - mean) / eps."""
    out = tmp_path_factory.mktemp("cml_runs")
    assert cli.main(["train", str(ROOT / "configs/tasks/follow.yaml"), "--model", "cml", "--runs", str(out),
                     *TINY, "train.max_iterations=1", "--no-eval"]) == 0
    (source,) = find_runs(out)
    saved = torch.load(sorted(source.checkpoints.glob("model_*.pt"))[-1], weights_only=True)["actor_state_dict"]
    z, actor = _carry_inputs_after_init(source.path, "cml_incremental", "restart")
    norm = actor.obs_normalizer
    assert int(norm.count) == int(saved["obs_normalizer.count"]) > 0  # kept, not restarted
    unseen = (saved["obs_normalizer._var"] <= 1e-12).reshape(-1)
    assert 0 < int(unseen.sum()) < unseen.numel()
    assert float(z[..., unseen].max()) < 1e-3
    torch.testing.assert_close(norm._mean, saved["obs_normalizer._mean"])


def test_a_later_stage_can_start_with_a_smaller_action_std(follow_run: Path, tmp_path: Path,
                                                          capsys: pytest.CaptureFixture[str]) -> None:
    """At the later stages' learning rate the std parameter never moves: the puppet kept
    Follow's std 1.0 through Carry, and its noise dropped every held box within steps."""
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", "mlp", TINY + [
        f"train.init_from={follow_run}", "train.init_action_std=0.3"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    with warnings.catch_warnings():
        warnings.simplefilter("error")  # reading the std once warned of a tensor that requires grad
        line = load_initial_weights(runner, cfg)
    assert "action std 1.00 -> 0.3" in line
    torch.testing.assert_close(runner.alg.actor.distribution.std_param,
                               torch.full((env.num_actions,), 0.3))
    kept = resolve_run(ROOT / "configs/tasks/carry.yaml", "mlp", TINY + [
        f"train.init_from={follow_run}"])
    _env, runner = build_runner(kept, None, "cpu", progress=False)
    load_initial_weights(runner, kept)
    assert float(runner.alg.actor.distribution.std_param.detach().min()) > 0.9  # the source's, kept
    capsys.readouterr()
    assert cli.main(["train", str(ROOT / "configs/tasks/carry.yaml"), "--model", "mlp", "--runs",
                     str(tmp_path / "runs"), *TINY, "train.init_action_std=0.3"]) == 2
    assert "train.init_action_std" in capsys.readouterr().err
    assert not (tmp_path / "runs").exists() or not any((tmp_path / "runs").iterdir())


def test_merged_statistics_keep_what_the_policy_learned_from_and_take_the_rest_from_the_new_task(
        follow_run: Path) -> None:
    """The default. Restarted statistics changed what the Follow policy did with inputs it had
    learned from (after one Carry rollout it no longer walked to the box); kept ones blew up the
    inputs Follow never varied. Merged: the seen inputs keep Follow's statistics, the unseen
    ones read ~0 (the constant the policy knew) until the first update sets them from Carry."""
    source = torch.load(sorted((follow_run / "checkpoints").glob("model_*.pt"))[-1], weights_only=True)
    saved = source["actor_state_dict"]
    unseen = (saved["obs_normalizer._var"] <= 1e-12).reshape(-1)
    assert 0 < int(unseen.sum()) < unseen.numel()
    z, actor = _carry_inputs_after_init(follow_run, "mlp", "merge")
    norm = actor.obs_normalizer
    assert int(norm.count) == int(saved["obs_normalizer.count"])
    assert float(z[..., unseen].max()) < 1e-3
    torch.testing.assert_close(norm._mean, saved["obs_normalizer._mean"])
    torch.testing.assert_close(norm._std[..., ~unseen], saved["obs_normalizer._std"][..., ~unseen])
    # the head's first layer read the unseen inputs with its random initial weights: now zero,
    # every other weight as trained
    first = actor.mlp[0].weight
    reads = unseen[actor.trunk.output_columns()[:, 0]]  # the kept frames' inputs, in head order
    assert 0 < int(reads.sum()) < len(reads)
    assert bool((first[:, reads] == 0).all())
    torch.testing.assert_close(first[:, ~reads], saved["mlp.0.weight"][:, ~reads])
    batch = torch.randn(64, norm._mean.shape[-1]) * 3.0 + 2.0
    norm.train()
    norm.update(batch)
    torch.testing.assert_close(norm._mean[0, unseen], batch.mean(0)[unseen])
    torch.testing.assert_close(norm._var[0, unseen], batch.var(0, unbiased=False)[unseen])
    rate = 64 / (int(saved["obs_normalizer.count"]) + 64)  # rsl-rl's update for the seen inputs
    expected = saved["obs_normalizer._mean"][0, ~unseen] * (1 - rate) + batch.mean(0)[~unseen] * rate
    torch.testing.assert_close(norm._mean[0, ~unseen], expected)
    before = norm._mean.clone()
    norm.update(batch * 0.0)  # later updates are rsl-rl's own, for every input
    assert bool((norm._mean[0, unseen] != before[0, unseen]).any())


@pytest.mark.parametrize("model", ["mlp", "detach"])
def test_a_later_stage_can_start_the_grasp_at_a_chosen_mean(follow_run: Path, tmp_path: Path, model: str,
                                                        capsys: pytest.CaptureFixture[str]) -> None:
    """Follow has nothing to hold, so its policy's grasp mean is whatever PPO's noise left: in
    one Follow cell -0.6 at the box, where Carry's exploration never asked for a grasp. The
    puppet's height target below standing is carried by its legs, and its hinges move nothing Follow
    pays for, so Follow leaves them drifting too; each is named (`Puppet.named_actions`)."""
    source = follow_run
    if model != "mlp":
        out = tmp_path / "follow"
        assert cli.main(["train", str(ROOT / "configs/tasks/follow.yaml"), "--model", model, "--runs", str(out),
                         *TINY, "train.max_iterations=1", "--no-eval"]) == 0
        (run,) = find_runs(out)
        source = run.path
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", model, TINY + [
        f"train.init_from={source}", "train.init_action_mean={grasp: 0.1, height: -0.05, abdomen_y: 0.5}"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    layers = [m for m in runner.alg.actor.mlp.modules() if isinstance(m, torch.nn.Linear)]
    saved = torch.load(sorted((source / "checkpoints").glob("model_*.pt"))[-1], weights_only=True)
    grasp, height, abdomen = env.num_actions - 1, env.num_actions - 2, DOF_NAMES.index("abdomen_y")
    said = load_initial_weights(runner, cfg)
    assert "grasp mean 0.1 in every state" in said and "height mean -0.05 in every state" in said
    assert "abdomen_y mean 0.5 in every state" in said
    actor = runner.alg.actor
    obs = env.get_observations()
    with torch.no_grad():
        mean = actor(obs)
    torch.testing.assert_close(mean[:, grasp], torch.full_like(mean[:, grasp], 0.1))
    torch.testing.assert_close(mean[:, height], torch.full_like(mean[:, height], -0.05))
    torch.testing.assert_close(mean[:, abdomen], torch.full_like(mean[:, abdomen], 0.5))
    rest = [a for a in range(height) if a != abdomen]
    assert mean[:, rest].std(0).max() > 0  # the other actions still depend on the state
    out_weight = layers[-1].weight
    key = next(k for k, v in saved["actor_state_dict"].items() if k.startswith("mlp.") and v.shape == out_weight.shape)
    torch.testing.assert_close(out_weight[rest], saved["actor_state_dict"][key][rest])  # the rest as loaded
    # a name the character does not have, or no policy to start from: one-line errors, nothing written
    for bad, words in (([f"train.init_from={source}", "+train.init_action_mean.grip=0.1"], "found 'grip'"),
                       ([f"train.init_from={source}", "+train.init_action_mean.grasp=2"], "in [-1, 1]"),
                       (["+train.init_action_mean.grasp=0.1"], "starts from scratch")):
        capsys.readouterr()
        assert cli.main(["train", str(ROOT / "configs/tasks/carry.yaml"), "--model", model, "--runs",
                         str(tmp_path / "runs"), *TINY, *bad]) == 2
        err = capsys.readouterr().err
        assert "train.init_action_mean" in err and words in err, err
    assert not (tmp_path / "runs").exists()


def test_a_stage_starts_from_the_choice_of_action_means_that_scores_best(
        follow_run: Path, monkeypatch: pytest.MonkeyPatch) -> None:
    """`train.init_action_mean_choices`: each choice plays the same validation trials (the
    scores here are the policy's grasp mean at the trials' first state); the best starts the
    stage, the first of a tie, with every other output row as loaded."""
    from detach.runs import start_choice, validation

    starts, seen = [], []

    def fake_evaluation(env, policy, trials, cfg, **_kw):
        obs = env.get_observations()
        starts.append(env.state.root_pos.clone())
        seen.append(trials)
        with torch.no_grad():
            rate = float(policy(obs)[:, -1].mean())  # the grasp: the puppet's last action
        return SimpleNamespace(lh_mean=SimpleNamespace(rate=rate))

    monkeypatch.setattr(validation, "run_evaluation", fake_evaluation)
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", "mlp", TINY + [
        f"train.init_from={follow_run}", "train.init_choice_trials=3",
        "train.init_action_mean_choices=[{grasp: -0.5}, {grasp: 0.7, height: -0.1}, {grasp: 0.7}]"])
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    load_initial_weights(runner, cfg)
    actor = runner.alg.actor
    layer = [m for m in actor.mlp.modules() if isinstance(m, torch.nn.Linear)][-1]
    loaded = layer.weight.detach().clone()
    line = start_choice.choose_action_means(actor, cfg, "cpu")
    assert "{grasp: -0.5}: -0.50; {grasp: 0.7, height: -0.1}: 0.70; {grasp: 0.7}: 0.70" in line, line
    assert "starting from choice 1" in line and "height mean -0.1" in line
    assert seen == [3, 3, 3]
    torch.testing.assert_close(starts[1], starts[0])
    torch.testing.assert_close(starts[2], starts[0])
    torch.testing.assert_close(layer.bias[-2:].detach(), torch.tensor([-0.1, 0.7]))
    torch.testing.assert_close(layer.weight[:-2].detach(), loaded[:-2])


def test_choices_of_action_means_run_through_the_cli_and_are_checked(
        follow_run: Path, tmp_path: Path, capsys: pytest.CaptureFixture[str]) -> None:
    out = tmp_path / "runs"
    assert cli.main(["train", str(ROOT / "configs/tasks/carry.yaml"), "--model", "mlp", "--runs", str(out), *TINY,
                     "train.max_iterations=1", "--no-eval", f"train.init_from={follow_run}",
                     "train.init_choice_trials=2", "train.init_action_mean_choices=[{grasp: -1.0}, {grasp: 1.0}]"]) == 0
    said = capsys.readouterr().out
    assert "LH mean over 2 validation trials each: {grasp: -1}: " in said and "starting from choice" in said, said
    for bad, key, words in (
            (["train.init_action_mean_choices=[{grasp: 0.1}, {grip: 0.1}]"], "train.init_action_mean_choices[1].grip",
             "found 'grip'"),
            (["train.init_action_mean_choices=[{grasp: 0.1}]", "+train.init_action_mean.grasp=0.1"],
             "train.init_action_mean_choices", "keep one of the two")):
        assert cli.main(["train", str(ROOT / "configs/tasks/carry.yaml"), "--model", "mlp", "--runs",
                         str(tmp_path / "bad"), *TINY, f"train.init_from={follow_run}", *bad]) == 2
        err = capsys.readouterr().err
        assert key in err and words in err, err
    assert not (tmp_path / "bad").exists()


def test_a_critic_warmup_trains_the_critic_alone_first(follow_run: Path) -> None:
    """`train.critic_warmup_iterations`: a stage started from another task's run fits its
    critic to the new rewards (at its own learning rate) before PPO moves the policy."""
    cfg = resolve_run(ROOT / "configs/tasks/carry.yaml", "mlp", TINY + [
        f"train.init_from={follow_run}", "train.critic_warmup_iterations=1", "train.max_iterations=2",
        "train.learning_rate=1.0e-5", "train.critic_warmup_learning_rate=1.0e-2"])
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    load_initial_weights(runner, cfg)
    alg = runner.alg

    def params(module: torch.nn.Module) -> dict[str, torch.Tensor]:
        return {k: v.detach().clone() for k, v in module.named_parameters()}

    actor0, critic0 = params(alg.actor), params(alg.critic)
    runner.learn(1)  # iteration 0: the critic alone
    actor1, critic1 = params(alg.actor), params(alg.critic)
    assert all(torch.equal(actor0[k], actor1[k]) for k in actor0)
    assert max(float((critic1[k] - critic0[k]).abs().max()) for k in critic0) > 1e-3  # at 1e-2, not 1e-5
    assert alg.learning_rate == 1.0e-5 and all(g["lr"] == 1.0e-5 for g in alg.optimizer.param_groups)
    assert all(p.requires_grad for p in alg.actor.parameters())
    runner.learn(2)  # iteration 1: PPO as usual
    assert any(not torch.equal(actor1[k], v) for k, v in params(alg.actor).items())
