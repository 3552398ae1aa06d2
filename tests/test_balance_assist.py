"""The balance assist (`train.balance_assist`): a righting torque on the humanoid's pelvis that
keeps it from tipping over while a policy learns to walk, fading out over training, and
absent from every evaluation."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach.config import resolve
from detach.envs.assist import MAX_SPIN, MAX_TILT, righting_wrench
from detach.motion.builtin import default_motion_lib
from detach.train.motion_bridge import reset_reference_sampler, start_clip_labels
from detach.train.setup import build_runner
from detach.train.start_library import make_training_env

ROOT = Path(__file__).resolve().parents[1]
ASSIST = ["train.balance_assist.torque=1000", "train.balance_assist.damping=30"]


def _falls(torque: float, damping: float, steps: int = 90) -> int:
    """Episodes ended by a fall of 16 humanoids holding the standing pose (zero actions) from
    walking and turning clip starts."""
    torch.set_num_threads(1)
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp",
                  ["env.init=random", "env.fall_rule=body", "env.height_map.enabled=false"], seed=3)
    env = make_training_env(cfg, num_envs=16, verbose=False)
    env.set_reference_sampler(reset_reference_sampler(default_motion_lib(), start_clip_labels(cfg)))
    env.reset()
    env.world.assist.set(torque, damping)
    fell = 0
    for _ in range(steps):
        _obs, _rew, _dones, extras = env.step(torch.zeros(16, env.num_actions))
        fell += int(torch.as_tensor(extras["log"].get("Episode_Termination/fell", 0.0)).sum())
    return fell


def test_the_assist_keeps_a_standing_humanoid_from_tipping_over():
    unassisted, assisted = _falls(0.0, 0.0), _falls(1000.0, 30.0)
    assert unassisted >= 3 and assisted == 0, (unassisted, assisted)


def test_switching_the_assist_off_removes_the_torque():
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp", [], seed=0)
    env = make_training_env(cfg, num_envs=2, verbose=False)
    env.reset()
    env.world.assist.set(1000.0, 30.0)
    env.step(torch.zeros(2, env.num_actions))
    env.step(torch.zeros(2, env.num_actions))
    pelvis = env.index.body[0]
    assert env.backend.get_data(0).xfrc_applied[pelvis, 3:].any()
    env.world.assist.set(0.0, 0.0)
    env.step(torch.zeros(2, env.num_actions))
    assert not env.backend.get_data(0).xfrc_applied.any()


def test_the_strength_holds_then_fades_to_zero():
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp",
                  [*ASSIST, "train.balance_assist.hold_iterations=2", "train.balance_assist.fade_iterations=4"])
    assist = cfg.train.balance_assist
    assert [assist.scale(i) for i in (0, 1, 2, 3, 4, 6, 50)] == pytest.approx([1, 1, 1, 0.75, 0.5, 0, 0])
    assert resolve(ROOT / "configs/tasks/follow.yaml", "mlp", []).train.balance_assist.scale(0) == 0.0


def test_training_logs_the_assist_and_evaluation_envs_have_none():
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", "mlp",
                  [*ASSIST, "train.balance_assist.hold_iterations=1", "train.balance_assist.fade_iterations=2",
                   "sim.num_envs=4", "train.num_steps_per_env=4", "train.num_mini_batches=2",
                   "train.num_learning_epochs=1", "env.height_map.enabled=false"])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    seen: list[float] = []
    runner.on_iteration = lambda _it, metrics: seen.append(metrics["Train/balance_assist"])
    runner.learn(4)
    assert seen == pytest.approx([1.0, 1.0, 0.5, 0.0])
    assert env.world.assist.gains is None  # the last zero wrench was written and the assist is gone
    evaluation = make_training_env(cfg, num_envs=2, verbose=False)
    assert evaluation.world.assist.gains is None


def test_the_torque_rights_a_small_tilt_and_stays_bounded_upside_down():
    half = torch.tensor([0.05, 1.5, 3.1]) / 2  # pitch forward by 0.05, 1.5 and 3.1 rad (about +y)
    quat = torch.stack((half.cos(), torch.zeros(3), half.sin(), torch.zeros(3)), dim=-1)
    spin = torch.tensor([[0.0, 0.0, 0.0], [0.0, 50.0, 0.0], [30.0, 0.0, 9.0]])
    wrench = righting_wrench(quat, spin, 1000.0, 30.0)
    assert torch.all(wrench[:, :3] == 0)
    assert wrench[0, 4] == pytest.approx(-50.0, rel=1e-3) and wrench[0, [3, 5]].abs().max() < 1e-4  # back about -y
    assert wrench[:, 5].abs().max() == 0  # yaw is never touched
    assert wrench[:, 3:].norm(dim=-1).max() <= 1000.0 * MAX_TILT + 30.0 * MAX_SPIN + 1e-3
