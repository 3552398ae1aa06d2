"""`env.subtask_start_prob`: training episodes of a long plan that begin at a later subtask,
from states the scripted oracle recorded (detach.envs.subtask_starts). Without them, Climb and
Sit inside LH1 get no samples until Follow and Carry are mastered."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach import cli
from detach.character.puppet import GRASP_ACTION
from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.train.runner import rollout_means
from detach.train.start_library import make_training_env

ROOT = Path(__file__).resolve().parents[1]
LH1 = ROOT / "configs/tasks/lh1.yaml"


def _env(prob: float, n: int = 8, eval_mode: bool = False):
    cfg = resolve(LH1, "mlp", ["env.character=puppet", f"env.subtask_start_prob={prob}"])
    return make_env(cfg, num_envs=n, verbose=False, eval_mode=True) if eval_mode else \
        make_training_env(cfg, num_envs=n, verbose=False)


@pytest.fixture(scope="module")
def late_env():
    """One env for the module: recording the oracle's LH1 episodes takes tens of seconds."""
    return _env(1.0, n=16)


def test_episodes_begin_at_later_subtasks_in_the_oracles_state(late_env) -> None:
    env = late_env
    starts = env.subtask_starts
    assert starts is not None and set(starts.subtask.tolist()) == {1, 2, 3}  # LH1: follow, carry, climb, sit
    sub = env.tracker.subtask
    assert bool((sub >= 1).all()) and len(set(sub.tolist())) >= 2
    ar = torch.arange(env.tracker.num_subtasks)
    assert torch.equal(env.tracker.done, ar[None, :] < sub[:, None])  # the earlier subtasks count as done
    # an episode that begins at climb (after carry) finds the box at its destination
    ctx = env.context()
    after_carry = sub == 2
    box = env.plan[1].obj
    target = torch.tensor(env.plan[1].fixed_target)
    if bool(after_carry.any()):
        d = (env.state.obj_pos[after_carry, box] - target).norm(dim=-1)
        assert bool((d <= env.cfg.env.success_threshold + 0.05).all())
    a = torch.zeros(env.num_envs, env.num_actions)
    for _ in range(5):
        obs = env.step(a)[0]
    assert all(bool(torch.isfinite(v).all()) for v in obs.values())
    assert bool(torch.isfinite(ctx.dist).all())


def test_evaluation_and_the_default_begin_at_the_first_subtask() -> None:
    assert _env(1.0, eval_mode=True).subtask_starts is None
    env = _env(0.0)
    assert env.subtask_starts is None and bool((env.tracker.subtask == 0).all())


def test_training_success_counts_an_episode_from_the_subtask_it_began_at(late_env) -> None:
    """An episode that began at a later subtask counts in the success of that subtask and the
    ones after it, not in the earlier ones' nor the whole plan's (it did not do them). Before,
    such episodes were left out of every `Episode_Success/` value, so a run with most of its
    episodes starting later logged its later subtasks' success rarely."""
    env = late_env
    env.max_episode_length = 10  # time every episode out soon (the recording needed the full length)
    a = torch.zeros(env.num_envs, env.num_actions)
    logs, begins = [], []
    for _ in range(25):
        begin = env.tracker.begin.clone()
        _obs, _rew, dones, extras = env.step(a)
        if "episode_progress" in extras:
            logs.append(extras["log"])
            begins.append(begin[torch.nonzero(dones).flatten()])
    assert bool(env.tracker.started_mid_task.all())  # every reset began later again
    assert logs and all(bool(log["Episode_Success/lh"].isnan().all()) for log in logs)
    assert all(bool(log["Episode_Success/0_follow"].isnan().all()) for log in logs)
    for log, begin in zip(logs, begins):
        for i, name in enumerate(("0_follow", "1_carry", "2_climb", "3_sit")):
            assert torch.equal(log[f"Episode_Success/{name}"].isnan(), begin > i)
    merged: dict[str, list[torch.Tensor]] = {}
    for log in logs:
        for k, v in log.items():
            merged.setdefault(k, []).append(torch.as_tensor(v).flatten())
    means = rollout_means(merged)  # what the training log shows
    assert "Episode_Success/3_sit" in means and "Episode_Success/0_follow" not in means
    assert "Episode_Success/lh" not in means


@pytest.mark.parametrize("task, overrides, why", [
    ("lh1", ["env.character=humanoid"], "cannot drive character 'humanoid'"),
    ("carry", ["env.character=puppet"], "has one subtask"),
])
def test_a_start_the_oracle_cannot_make_is_a_config_error(tmp_path: Path, capsys: pytest.CaptureFixture,
                                                          task: str, overrides: list[str], why: str) -> None:
    rc = cli.main(["train", task, "--model", "mlp", "--runs", str(tmp_path), "--no-eval",
                   "env.subtask_start_prob=0.5", "train.max_iterations=1", *overrides])
    err = capsys.readouterr().err
    assert rc == 2 and "env.subtask_start_prob" in err and why in err
    assert not any(tmp_path.iterdir())


def test_a_box_held_into_climb_is_let_go(late_env) -> None:
    """Carry's transition may fire with the box still held; Climb must not keep it (a Climb
    policy that held the box it was to climb carried it away: results/laptop/NOTEBOOK.md)."""
    env = late_env
    sub = env.tracker.subtask.clone()
    box = env.plan[1].obj
    slot = env.world.dyn_slot[box]
    ids = torch.nonzero((sub == 1) | (sub == 2)).flatten()
    assert bool((sub[ids] == 1).any()) and bool((sub[ids] == 2).any())
    st = env.state
    env.character.hold(ids, slot.expand(len(ids)), st.root_pos[ids], st.root_quat[ids],
                       st.obj_pos[ids, box], st.obj_quat[ids, box])
    a = torch.zeros(env.num_envs, env.num_actions)
    a[:, GRASP_ACTION] = 1.0
    env.step(a)
    now = env.character.held_object()
    still = env.episode_length_buf > 0
    climbing, carrying = ids[(sub[ids] == 2) & still[ids]], ids[(sub[ids] == 1) & still[ids]]
    assert len(climbing) and len(carrying)
    assert bool((now[climbing] == -1).all())
    assert bool((now[carrying] == slot).all())
