"""The batched LH environment: VecEnv contract, observation sizes, plan transitions,
terminations, and the oracle / random figures at small trial counts."""

from __future__ import annotations

import dataclasses
from pathlib import Path

import pytest
import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict

from types import SimpleNamespace

from detach.config import resolve
from detach.config.schema import HumanoidCfg, TaskCfg
from detach.envs.lh_env import make_env
from detach.envs.oracle import Oracle, random_policy
from detach.envs.rewards import RewardManager
from detach.eval.episodes import run_evaluation
from detach.skills import PlanError, skill_index
from detach.skills.climb import climb_distance
from detach.skills.plan import compile_plan

TASKS = Path(__file__).resolve().parents[1] / "configs" / "tasks"
torch.set_num_threads(1)


def cfg_of(task: str, *overrides: str):
    return resolve(TASKS / f"{task}.yaml", "mlp", list(overrides))


@pytest.fixture(scope="module")
def lh_envs():
    return {t: make_env(cfg_of(t), num_envs=2) for t in ("lh1", "lh2", "lh3")}


def test_vecenv_contract_and_obs_sizes_equal_across_lh(lh_envs):
    specs = {t: e.obs_spec for t, e in lh_envs.items()}
    assert len(set(specs.values())) == 1, specs
    for env in lh_envs.values():
        assert isinstance(env, VecEnv) and env.num_actions == 32 and env.max_episode_length == 1200
        obs = env.get_observations()
        assert isinstance(obs, TensorDict) and obs.batch_size == torch.Size([2])
        assert {k: v.shape[1] for k, v in obs.items()} == env.obs_spec.group_dims()
        obs, rew, dones, extras = env.step(torch.zeros(2, env.num_actions))
        assert rew.shape == (2,) and dones.shape == (2,) and extras["time_outs"].shape == (2,)
        assert all(torch.isfinite(v).all() for v in obs.values())
        assert any(k.startswith("Episode_Reward/") for k in extras["log"])
    sp = specs["lh1"]
    assert (sp.self_dim, sp.env_dim, sp.amp_dim, sp.num_skills) == (287, 681, 89, 4)


def test_height_map_sees_static_objects():
    env = make_env(cfg_of("climb", "env.character=puppet", "humanoid.init_rot_randomize=false"), num_envs=1)
    # climb.yaml: a 0.5 m platform centred 2.5 m ahead of the start, footprint 1.2 m
    hm = env.get_observations()["env"].reshape(5, -1)[-1, -625:].reshape(25, 25)
    assert hm[12, 12] == pytest.approx(0.0)  # under the pelvis: floor
    assert hm[24, 12] == pytest.approx(0.0)  # 1.2 m ahead: still floor (platform edge at 1.9 m)
    qpos = env.backend.qpos[:1].clone()
    qpos[0, 0] = 1.6  # now the platform edge is 0.3 m ahead
    env.backend.write_qpos(torch.tensor([0]), qpos)
    obs, *_ = env.step(torch.zeros(1, env.num_actions))
    hm = obs["env"].reshape(5, -1)[-1, -625:].reshape(25, 25)
    assert hm[24, 12] == pytest.approx(0.5, abs=0.01) and hm[12, 12] == pytest.approx(0.0, abs=0.01)


def _two_point_plan_cfg(**env_kw):
    base = cfg_of("follow", "env.character=puppet")
    task = TaskCfg(name="hold_test", trajectories={0: ((0.0, 0.0),), 1: ((0.0, 0.0), (8.0, 0.0))},
                   humanoid=HumanoidCfg(init_pos2d=(0.0, 0.0), init_rot_randomize=False),
                   plan=("follow", "traj"), target_object=(0, 0), sample_target_from=("traj_0", "traj_1"))
    return dataclasses.replace(base, task=task, env=dataclasses.replace(base.env, **env_kw))


@pytest.mark.parametrize("eval_mode,hold", [(False, 60), (True, 20)])
def test_transition_fires_exactly_after_hold_time(eval_mode, hold):
    env = make_env(_two_point_plan_cfg(), num_envs=2, eval_mode=eval_mode)
    assert env.max_transition_steps == hold
    still = torch.zeros(2, env.num_actions)  # the puppet stands on trajectory 0's only point
    for k in range(1, hold):
        env.step(still)
        assert env.tracker.subtask.tolist() == [0, 0] and env.tracker.hold.tolist() == [k, k]
    _, _, dones, _ = env.step(still)
    assert env.tracker.subtask.tolist() == [1, 1] and not dones.any()
    prog = env.tracker.progress()
    assert prog["end"][:, 0].tolist() == [hold, hold] and prog["start"][:, 1].tolist() == [hold, hold]
    assert prog["done"][:, 0].all() and not prog["done"][:, 1].any()


def test_iet_and_time_out():
    env = make_env(dataclasses.replace(_two_point_plan_cfg(), task=dataclasses.replace(
        _two_point_plan_cfg().task, plan=("follow",), target_object=(0,), sample_target_from=("traj_0",))),
        num_envs=1, eval_mode=True)
    for _ in range(19):
        _, _, dones, _ = env.step(torch.zeros(1, env.num_actions))
        assert not dones.any()
    _, _, dones, extras = env.step(torch.zeros(1, env.num_actions))  # last subtask held: IET
    assert dones.all() and extras["time_outs"].all()
    assert extras["episode_progress"]["lh_success"].all() and env.episode_length_buf.item() == 0
    short = make_env(_two_point_plan_cfg(episode_length=5), num_envs=1)
    for _ in range(5):
        _, _, dones, extras = short.step(torch.zeros(1, short.num_actions))
    assert dones.all() and extras["time_outs"].all() and short.episode_length_buf.item() == 0
    assert extras["episode_progress"]["length"].item() == 5 and "Episode_Termination/fell" in extras["log"]


def test_fall_terminates_and_resets():
    env = make_env(cfg_of("follow", "humanoid.init_rot_randomize=false"), num_envs=2)
    gen = torch.Generator().manual_seed(1)
    for _ in range(300):
        a = torch.rand(2, env.num_actions, generator=gen) * 2 - 1
        _, _, dones, extras = env.step(a)
        if dones.any():
            break
    assert dones.any(), "random PD targets should topple the humanoid within 10 s"
    prog = extras["episode_progress"]
    i = int(dones.nonzero()[0])
    assert prog["fell"][i] and not extras["time_outs"][i]
    assert env.episode_length_buf[i] == 0
    assert env.state.root_pos[i, 2] == pytest.approx(0.94, abs=1e-3)


def _steps_to_first_fall(env, seed: int = 1) -> int:
    gen = torch.Generator().manual_seed(seed)
    for t in range(300):
        _, _, dones, extras = env.step(torch.rand(1, env.num_actions, generator=gen) * 2 - 1)
        if dones.any():
            assert extras["episode_progress"]["fell"].all()
            return t
    raise AssertionError("random PD targets should topple the humanoid within 10 s")


def test_body_fall_rule_ends_the_episode_when_a_body_touches_down_before_the_pelvis():
    """`env.fall_rule: body` (AMP's early termination): a knee, hand or head at the floor ends
    the episode while the pelvis is still up; the default rule waits for the pelvis."""
    pelvis = make_env(cfg_of("follow", "humanoid.init_rot_randomize=false", "env.init=default"), num_envs=1)
    body = make_env(cfg_of("follow", "humanoid.init_rot_randomize=false", "env.init=default",
                           "env.fall_rule=body"), num_envs=1)
    t_pelvis, t_body = _steps_to_first_fall(pelvis), _steps_to_first_fall(body)
    assert t_body < t_pelvis
    replay = make_env(pelvis.cfg, num_envs=1)  # the same start and actions, still running at t_body
    gen = torch.Generator().manual_seed(1)
    for _ in range(t_body + 1):
        _, _, dones, _ = replay.step(torch.rand(1, replay.num_actions, generator=gen) * 2 - 1)
    heights = replay.state.body_pos[0, :, 2]
    assert not dones.any() and heights[0] > 0.15 and bool((heights < 0.15).any())


def test_traj_deviation_terminates():
    env = make_env(_two_point_plan_cfg(), num_envs=1)
    env.tracker.subtask[:] = 1  # trajectory 1 runs to x = 8 m at 1.45 m/s; standing still falls behind
    env.tracker.start(torch.tensor([True]), env.steps, torch.zeros(1, 2))
    for t in range(200):
        _, _, dones, extras = env.step(torch.zeros(1, env.num_actions))
        if dones.any():
            break
    assert extras["episode_progress"]["traj_failed"].all() and not extras["time_outs"].any()
    assert 2.5 < t * env.dt < 3.2  # 4 m at 1.45 m/s


def test_plan_errors_are_one_line():
    bad = TaskCfg(name="t", plan=("carry",), target_object=(0,), sample_target_from=("scene_0",))
    with pytest.raises(PlanError, match="scene_K names the box itself") as err:
        compile_plan(dataclasses.replace(bad, scene=cfg_of("carry").task.scene))
    assert err.value.key == ("sample_target_from", 0)
    with pytest.raises(PlanError, match="unknown skill 'jump'; available: follow, carry, climb, sit"):
        compile_plan(dataclasses.replace(bad, plan=("jump",)))
    with pytest.raises(ValueError, match="unknown term"):
        RewardManager(dataclasses.replace(cfg_of("follow").rewards, terms={"sit/sea": 1.0}), [])


def test_success_scores():
    env = make_env(cfg_of("lh2", "env.character=puppet"), num_envs=2)  # follow, carry, follow, sit
    t = env.tracker
    t.done[:] = torch.tensor([[True, False, True, False], [True, True, False, True]])
    t.stats["grasped"][:] = torch.tensor([[False, True, False, False], [False, True, False, False]])
    t.stats["on_path"][:] = torch.tensor([[95, 0, 95, 0], [50, 0, 0, 0]])
    t.stats["path_steps"][:] = torch.tensor([[100, 0, 100, 0], [100, 0, 0, 0]])
    prog = env.tracker.progress()
    assert prog["score"].tolist() == [[1.0, 0.5, 1.0, 0.0], [0.0, 1.0, 0.0, 1.0]]
    assert prog["lh_success"].tolist() == [False, False]
    root = torch.tensor([[0.0, 0.0, 2.0], [0.0, 0.0, 1.0]])
    tgt = torch.tensor([[0.1, 0.0, 1.6], [0.0, 0.0, 1.6]])
    assert climb_distance(root, tgt).tolist() == pytest.approx([0.1, 0.6])


@pytest.mark.parametrize("task", ["lh1", "lh2", "lh3"])
def test_oracle_succeeds_and_random_fails(task):
    cfg = cfg_of(task, "env.character=puppet")
    env = make_env(cfg, num_envs=4, eval_mode=True)
    oracle = Oracle(env)
    res = run_evaluation(env, lambda _obs: oracle(), trials=4, cfg=cfg, progress=False)
    assert res.lh_success.rate == 1.0, res.subtasks
    assert res.mean_execution_time < 40.0
    env = make_env(cfg, num_envs=4, eval_mode=True)
    rnd = run_evaluation(env, random_policy(env), trials=8, cfg=cfg, progress=False)
    assert rnd.lh_success.rate == 0.0


def test_oracle_needs_a_scriptable_character():
    env = make_env(cfg_of("follow"), num_envs=1)
    with pytest.raises(ValueError, match="set env.character to one of puppet"):
        Oracle(env)


def test_preview_cli_prints_the_oracle_timeline(capsys):
    from detach.envs.preview import main

    assert main([str(TASKS / "lh1.yaml"), "--oracle"]) == 0
    out = capsys.readouterr().out
    assert "subtask 2 (climb) complete -> 3 (sit)" in out and "LH success: True" in out


def test_follow_rewards_ask_to_keep_up_and_stop_at_the_end():
    from detach.skills.follow import position, precision, velocity

    def ctx(root_xy, root_v, ref_xy, ref_v):
        """The part of a SkillContext the follow terms read."""
        z = torch.zeros(len(root_xy))
        t = lambda rows: torch.tensor(rows, dtype=torch.float32)  # noqa: E731
        pos = torch.cat((t(root_xy), z[:, None] + 0.9), dim=-1)
        lin = torch.cat((t(root_v), z[:, None]), dim=-1)
        state = SimpleNamespace(root_pos=pos, body_lin=lin[:, None])
        return SimpleNamespace(state=state, ref_xy=t(ref_xy), ref_vel=t(ref_v), skill=z.long())

    # on the reference at its velocity; 0.5 m behind at its velocity; 0.5 m behind catching up
    c = ctx([[0, 0], [-0.5, 0], [-0.5, 0]], [[1.45, 0], [1.45, 0], [2.0, 0]],
            [[0, 0]] * 3, [[1.45, 0]] * 3)
    vel, prec, pos = velocity(c), precision(c), position(c)
    assert vel[0] == pytest.approx(1.0) and vel[2] == pytest.approx(1.0) and vel[1] < 0.9
    assert prec[0] == pytest.approx(1.0) and prec[1] < 0.01 and pos[1] > 0.6
    # the reference has stopped at the end point: standing on it pays, overshooting does not
    c = ctx([[0, 0], [0.3, 0]], [[0, 0], [1.0, 0]], [[0, 0]] * 2, [[0, 0]] * 2)
    assert velocity(c)[0] == pytest.approx(1.0) and velocity(c)[1] < 0.3
    assert skill_index("traj") == skill_index("follow") == 0
