"""`rewards.subtask_bonus` (a reward paid once at the step a subtask of a paid skill completes)
and `rewards.done_subtask_reward` (paid every step for each completed one), against the reward
a policy gives up by moving on (the oracle earns 1 per step on Follow's end point and 0.15 in
Carry's first ten steps)."""

from __future__ import annotations

from pathlib import Path

import torch

from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.envs.oracle import Oracle

ROOT = Path(__file__).resolve().parents[1]


def _oracle_rewards(overrides: list[str], steps: int, key: str = "bonus/subtask_done"
                    ) -> tuple[list[float], list[int], list[float]]:
    """Per step of one LH1 env driven by the oracle: reward, subtask, and the logged term key."""
    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "mlp", ["env.character=puppet", *overrides], seed=3)
    env = make_env(cfg, num_envs=1, verbose=False)
    oracle = Oracle(env)
    rewards, subtasks, logged = [], [], []
    for _ in range(steps):
        _obs, rew, _dones, extras = env.step(oracle())
        rewards.append(float(rew[0]))
        subtasks.append(int(env.tracker.subtask[0]))
        logged.append(float(extras["log"].get(f"Episode_Reward/{key}", torch.nan)))
    return rewards, subtasks, logged


def test_the_bonus_is_paid_once_when_a_paid_subtask_completes() -> None:
    torch.set_num_threads(1)
    steps = 300  # the oracle finishes LH1's Follow after ~240 steps
    plain, subtasks, _ = _oracle_rewards([], steps)
    paid, subtasks_paid, logged = _oracle_rewards(["rewards.subtask_bonus=20"], steps)
    assert subtasks_paid == subtasks, "the bonus must not change what the env does"
    moved = [t for t in range(1, steps) if subtasks[t] != subtasks[t - 1]]
    assert len(moved) == 1 and subtasks[moved[0]] == 1, "Follow's transition fired once"
    extra = [round(b - a, 4) for a, b in zip(plain, paid)]
    assert extra[moved[0]] == 20.0
    assert all(x == 0.0 for t, x in enumerate(extra) if t != moved[0])
    assert logged[moved[0]] == 20.0 and logged[moved[0] - 1] == 0.0
    # Follow is not among the paid skills: no bonus at its transition
    unpaid, _, logged = _oracle_rewards(["rewards.subtask_bonus=20", "rewards.paid_skills=[carry]"], steps)
    assert unpaid[moved[0]] < 5.0 and all(x == 0.0 for x in logged if x == x)


def test_without_a_bonus_the_log_has_no_bonus_term() -> None:
    _, _, logged = _oracle_rewards([], 3)
    assert all(x != x for x in logged)  # NaN: the key is absent


def test_completed_subtasks_pay_every_step_after_they_complete() -> None:
    """`rewards.done_subtask_reward`: after Follow's transition the oracle's every step pays the
    reward of one completed subtask on top of what it paid before; nothing before it, and
    nothing for a completed subtask of an unpaid skill. Without it, the scripted oracle earns
    1.0 per step on Follow's end point and 0.15 in Carry's first steps, so moving on lowers
    the reward and a policy learned to dither 0.3-0.37 m from the path's end."""
    torch.set_num_threads(1)
    steps = 300
    plain, subtasks, _ = _oracle_rewards([], steps)
    paid, subtasks_paid, logged = _oracle_rewards(["rewards.done_subtask_reward=1.5"], steps, "bonus/subtasks_done")
    assert subtasks_paid == subtasks
    moved = next(t for t in range(1, steps) if subtasks[t] != subtasks[t - 1])
    extra = [round(b - a, 4) for a, b in zip(plain, paid)]
    assert all(x == 0.0 for x in extra[:moved]) and all(x == 1.5 for x in extra[moved:])
    assert logged[moved - 1] == 0.0 and logged[moved] == 1.5
    assert min(paid[moved:moved + 10]) > max(plain[moved - 10:moved]), "moving on pays more than the end point"
    unpaid, _, _ = _oracle_rewards(["rewards.done_subtask_reward=1.5", "rewards.paid_skills=[carry]"], steps)
    follow_unpaid, _, _ = _oracle_rewards(["rewards.paid_skills=[carry]"], steps)
    assert unpaid == follow_unpaid


def test_a_late_start_counts_the_subtasks_it_skipped_as_completed() -> None:
    """An episode that begins at a later subtask (`env.subtask_start_prob`) is paid for the
    subtasks before it, as one that completed them."""
    from detach.envs.rewards import RewardManager
    from detach.skills.plan import compile_plan

    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "mlp", ["rewards.done_subtask_reward=2"])
    plan = compile_plan(cfg.task)  # follow, carry, climb, sit
    manager = RewardManager(cfg.rewards, plan)
    assert manager.done_pay(torch.tensor([0, 1, 2, 3])).tolist() == [0.0, 2.0, 4.0, 6.0]
    assert RewardManager(resolve(ROOT / "configs/tasks/lh1.yaml", "mlp", []).rewards, plan).done_pay(
        torch.tensor([1])) is None
