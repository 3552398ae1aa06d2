"""Climb's reward pays for rising within reach of the object, not only once over its top."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach.character.puppet import height_to_action
from detach.config import resolve
from detach.envs.lh_env import make_env

TASKS = Path(__file__).resolve().parents[1] / "configs" / "tasks"
PLATFORM = 0.5  # climb.yaml: a 0.5 m platform centred 2.5 m ahead, footprint 1.2 m


def _rewards_at(x: float, raised: float) -> torch.Tensor:
    """Rewards [2] after one still step of two puppets at x (m) facing the platform, the first
    standing on the floor, the second with its pelvis held `raised` m higher."""
    cfg = resolve(TASKS / "climb.yaml", "detach",
                  ["env.character=puppet", "humanoid.init_rot_randomize=false", "rewards.power_coeff=0"])
    env = make_env(cfg, num_envs=2)
    qpos = env.backend.qpos.clone()
    qpos[:, 0], qpos[1, 2] = x, qpos[1, 2] + raised
    env.backend.write_qpos(torch.tensor([0, 1]), qpos)
    actions = torch.zeros(2, env.num_actions)
    actions[1, 35] = height_to_action(float(qpos[1, 2]))
    _, rew, _, _ = env.step(actions)
    return rew


def test_rising_at_the_edge_pays():
    # 0.2 m before the platform's edge (at 1.9 m): soles at the top's height earn the
    # feet_height term (0.3 x (1 - 0.29)); the elevation term alone paid ~0.02 for it.
    rew = _rewards_at(1.7, PLATFORM)
    assert rew[1] - rew[0] > 0.15, rew


def test_rising_far_from_the_object_pays_nothing():
    rew = _rewards_at(0.0, PLATFORM)
    assert rew[1] - rew[0] == pytest.approx(0.0, abs=0.01), rew


def test_a_tipped_box_keeps_its_climb_point_on_its_top():
    """A box knocked onto its side put Climb's target on its side at mid-height (the top's
    centre in the box's frame), so a policy standing beside it met the success rule."""
    cfg = resolve(TASKS / "lh1.yaml", "mlp", ["env.character=puppet"])
    env = make_env(cfg, num_envs=2, verbose=False)
    box = env.plan[2].obj  # LH1 climbs onto its box
    adr = env.scene.objects[box].qpos_adr
    half = env.index.obj_half[box]
    qpos = env.backend.qpos.clone()
    qpos[1, adr + 2] = half[1]  # env 1: the box lying on a side (90 degrees about x)
    qpos[1, adr + 3:adr + 7] = torch.tensor([0.5 ** 0.5, 0.5 ** 0.5, 0.0, 0.0])
    env.backend.write_qpos(torch.tensor([0, 1]), qpos)
    env.step(torch.zeros(2, env.num_actions))
    ctx = env.context()
    st = env.state
    ctx.obj = torch.full((2,), box)
    ctx.obj_pos, ctx.obj_quat = st.obj_pos[:, box], st.obj_quat[:, box]
    ctx.obj_half = half.expand(2, 3)
    ctx.has_fixed = torch.zeros(2, dtype=torch.bool)
    climb = next(s for s in env.tracker.skills.values() if s.name == "climb")
    target = climb.target(ctx)
    top = target[:, 2] - cfg.env.climb_pelvis_height
    assert top[0] == pytest.approx(float(2 * half[2]), abs=0.02)  # upright: 0.7 m
    assert top[1] == pytest.approx(float(2 * half[1]), abs=0.02)  # on its side: 0.6 m, not 0.3
    assert (target[:, :2] - st.obj_pos[:, box, :2]).norm(dim=-1).max() < 0.02
