"""`env.held_init_prob`: Carry episodes that start with the box carried part of the way
(TokenHSI's hybrid initialisation from box clips). Without them a Carry policy that never
grasps never learns what holding and carrying pay (results/laptop/README.md, "Carry")."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach import cli
from detach.character.puppet import GRASP_ACTION
from detach.character.body import START_HEIGHT
from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.skills.carry import LIFT, hands_on_box, walk_to_box

ROOT = Path(__file__).resolve().parents[1]
CARRY = ROOT / "configs/tasks/carry.yaml"


def _env(prob: float, eval_mode: bool = False, n: int = 16):
    cfg = resolve(CARRY, "mlp", ["env.character=puppet", f"env.held_init_prob={prob}"])
    return make_env(cfg, num_envs=n, verbose=False, eval_mode=eval_mode)


def test_held_starts_carry_the_episodes_box_lifted_between_its_place_and_the_destination() -> None:
    env = _env(1.0)
    ar = torch.arange(env.num_envs)
    box = env.tracker.objects[:, 0]
    st = env.state
    assert torch.equal(env.character.held_object(), env.dyn_slot[box])  # the episode's own box
    rest = env.resets.obj_rest[box]
    assert torch.allclose(st.obj_pos[ar, box, 2], rest[:, 2] + LIFT, atol=1e-4)
    target = torch.tensor(env.plan[0].fixed_target)
    to_dest = (st.obj_pos[ar, box, :2] - target[:2]).norm(dim=-1)
    assert bool((to_dest <= (rest[:, :2] - target[:2]).norm(dim=-1) + 1e-4).all())  # on the way, not beyond
    assert len(set(to_dest.round(decimals=2).tolist())) > env.num_envs // 2  # spread along the way
    assert bool(((st.root_pos[:, 2] - START_HEIGHT).abs() < 1e-3).all())
    ctx = env.context()
    assert bool((walk_to_box(ctx) == 1.0).all()) and bool((hands_on_box(ctx) == 1.0).all())  # stages done
    # holding on keeps the box up, even with the pelvis asked lower than the legs allow (a
    # Follow policy asks for 0.5 m and stands at 0.93 m); letting go drops it
    a = torch.zeros(env.num_envs, env.num_actions)
    a[:, GRASP_ACTION], a[:, 35] = 1.0, -0.3
    for _ in range(20):
        env.step(a)
    kept = env.episode_length_buf == 20
    assert int(kept.sum()) >= env.num_envs // 2
    z = env.state.obj_pos[ar, box, 2]
    assert torch.allclose(z[kept], rest[kept, 2] + LIFT, atol=0.02)
    a[:, GRASP_ACTION] = -1.0
    for _ in range(20):
        env.step(a)
    assert bool((env.character.held_object() == -1).all())
    z = env.state.obj_pos[ar, box, 2]
    kept = env.episode_length_buf == 40
    assert bool((z[kept] < rest[kept, 2] + LIFT - 0.05).all())


def test_evaluation_and_the_default_never_start_holding() -> None:
    assert bool((_env(1.0, eval_mode=True).character.held_object() == -1).all())
    assert bool((_env(0.0).character.held_object() == -1).all())
    half = _env(0.5, n=64).character.held_object()
    assert 12 < int((half >= 0).sum()) < 52


def test_a_character_that_cannot_hold_is_a_config_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    rc = cli.main(["train", "carry", "--model", "mlp", "--runs", str(tmp_path), "--no-eval",
                   "env.character=humanoid", "env.held_init_prob=0.25", "train.max_iterations=1"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "env.held_init_prob" in err and "humanoid" in err
    assert not any(tmp_path.iterdir())


def test_a_held_box_moving_with_the_character_is_not_penalised_as_thrown() -> None:
    """The box speed penalty is for kicked or thrown boxes. A box held at 2 m/s paid it at
    every step (1.1 per step under exploration noise, five times what holding earned), so
    Carry policies learned to drop the box."""
    env = _env(1.0, n=8)
    a = torch.zeros(env.num_envs, env.num_actions)
    a[:, GRASP_ACTION], a[:, 32] = 1.0, 1.0  # forward 2 m/s
    for _ in range(10):
        env.step(a)
    ctx = env.context()
    held = env.character.held_object() >= 0
    ar = torch.arange(env.num_envs)
    speed = ctx.dyn_speed[ar, env.character.held_object().clamp(min=0)]
    fast = held & (speed > env.cfg.rewards.dyn_obj_speed_threshold + 0.2)
    assert int(fast.sum()) >= 4
    _, parts = env.rewards.compute(ctx)
    assert bool((parts["penalty/dyn_obj_speed"][fast] == 0).all())
    ctx.held = torch.full_like(ctx.held, -1)  # the same motion of a box nobody holds
    _, parts = env.rewards.compute(ctx)
    assert bool((parts["penalty/dyn_obj_speed"][fast] < -0.1).all())
