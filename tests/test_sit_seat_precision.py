"""Sit near the seat: the opt-in `seat_precision` term (a sharper kernel on the pelvis's
distance to the sit point, paid only where it is switched on) and the oracle's descent onto
the seat, which a policy taught by the oracle must be able to follow."""

from __future__ import annotations

import math
from pathlib import Path

import pytest
import torch

from detach.config import resolve
from detach.envs.lh_env import make_env

ROOT = Path(__file__).resolve().parents[1]
N = 16


def _sit_env(overrides: list[str]):
    """Sit with every episode started mid-task: seated at the sit point or standing near it."""
    cfg = resolve(ROOT / "configs/tasks/sit.yaml", "mlp",
                  ["env.character=puppet", "env.mid_task_init_prob=1.0", *overrides], seed=3)
    return make_env(cfg, num_envs=N, verbose=False)


def test_seat_precision_pays_the_sharper_kernel_of_the_sit_distance() -> None:
    torch.set_num_threads(1)
    env = _sit_env(["+rewards.terms.sit/seat_precision=0.5"])
    _obs, rew, _dones, extras = env.step(torch.zeros(N, env.num_actions))
    _obs, rew_off, _dones, _extras = _sit_env([]).step(torch.zeros(N, env.num_actions))
    dist = env.context().dist
    assert (dist < 0.2).any() and (dist > 0.5).any()  # seated starts and standing ones
    # the same seed and actions give the same state: the step's reward differs by W x the kernel
    assert torch.allclose(rew - rew_off, 0.5 * torch.exp(-50.0 * dist ** 2), atol=1e-5)
    logged = float(extras["log"]["Episode_Reward/sit/seat_precision"])
    seat = float(extras["log"]["Episode_Reward/sit/seat"])
    assert logged == pytest.approx(float(torch.exp(-50.0 * dist ** 2).mean()), rel=1e-4, abs=1e-6)
    assert seat == pytest.approx(float(torch.exp(-10.0 * dist ** 2).mean()), rel=1e-4, abs=1e-6)
    # the sharper kernel is below the seat kernel wherever the pelvis is off the sit point
    assert logged <= seat


def test_seat_precision_is_off_by_default() -> None:
    env = _sit_env([])
    _obs, _rew, _dones, extras = env.step(torch.zeros(N, env.num_actions))
    assert "Episode_Reward/sit/seat_precision" not in extras["log"]
    assert "Episode_Reward/sit/seat" in extras["log"]
    assert math.isfinite(float(extras["log"]["Episode_Reward/sit/seat"]))


def test_the_oracle_comes_down_continuously_as_it_closes_on_the_sit_point() -> None:
    """The oracle's height command is continuous in the XY distance to the sit point. With a step
    at 4 cm (above the chair beyond, on the seat within), a policy taught by the oracle
    (`train.teachers.sit=oracle`) hovered 0.75 m above LH1's seat 5 cm off its centre."""
    from detach.skills.sit import DESCENT, descent_height

    d = torch.linspace(0.0, 0.5, 501)
    seat, above = torch.full_like(d, 1.55), torch.full_like(d, 2.3)
    z = descent_height(d, seat, above)
    assert torch.all(z[d <= DESCENT[0]] == 1.55) and torch.all(z[d >= DESCENT[1]] == 2.3)
    assert (z[1:] - z[:-1]).abs().max() < 0.01  # no jump between 1 mm steps
    assert z[50] < seat[0] + 0.1 * (above[0] - seat[0])  # 5 cm off: most of the way down
