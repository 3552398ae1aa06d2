"""`env.mid_task_init_prob`: Carry episodes that start with the box carried part of the way
(TokenHSI's hybrid initialisation from box clips), Climb episodes that start beside the
object. Without them a Carry policy that never grasps never learns what holding and carrying
pay (results/laptop/NOTEBOOK.md, "Carry")."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach import cli
from detach.character.puppet import GRASP_ACTION, GRASP_HAND_DIST
from detach.torch_math import heading_matrix, point_box_distance, yaw_of
from detach.character.body import START_HEIGHT
from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.skills.carry import APPROACH_RANGE, GRASP_LIFT, LIFT, box_lifted, hands_on_box, walk_to_box

ROOT = Path(__file__).resolve().parents[1]
CARRY = ROOT / "configs/tasks/carry.yaml"


def _env(prob: float, eval_mode: bool = False, n: int = 16, extra: tuple[str, ...] = ()):
    cfg = resolve(CARRY, "mlp", ["env.character=puppet", f"env.mid_task_init_prob={prob}", *extra])
    return make_env(cfg, num_envs=n, verbose=False, eval_mode=eval_mode)


def _started(n: int):
    """Every start mid-task: (env, env indices, each env's box, state, which start holding it)."""
    env = _env(1.0, n=n)
    return env, torch.arange(env.num_envs), env.tracker.objects[:, 0], env.state, env.character.held_object() >= 0


def test_mid_task_starts_hold_the_episodes_box_up_on_its_way_or_stand_at_it_or_near_it() -> None:
    env, ar, box, st, held = _started(48)
    rest = env.resets.obj_rest[box]
    to_box = (st.root_pos[:, :2] - rest[:, :2]).norm(dim=-1)
    approaching = ~held & (to_box > APPROACH_RANGE[0] - 0.01)
    at_box = ~held & ~approaching
    # 0.45 hold, 0.15 stand at the box, 0.4 stand some way off
    assert int(held.sum()) >= 10 and int(at_box.sum()) >= 2 and int(approaching.sum()) >= 8
    assert torch.equal(env.character.held_object()[held], env.world.dyn_slot[box][held])  # the episode's own box
    assert torch.allclose(st.obj_pos[ar, box, 2][held], rest[held, 2] + LIFT, atol=1e-4)
    assert torch.allclose(st.obj_pos[ar, box][~held], rest[~held], atol=1e-3)  # not held: where it rests
    target = torch.tensor(env.plan[0].fixed_target)
    to_dest = (st.obj_pos[ar, box, :2] - target[:2]).norm(dim=-1)
    assert bool((to_dest <= (rest[:, :2] - target[:2]).norm(dim=-1) + 1e-4).all())  # on the way, not beyond
    assert len(set(to_dest[held].round(decimals=2).tolist())) > int(held.sum()) // 2  # spread along the way
    assert bool(((st.root_pos[:, 2] - START_HEIGHT).abs() < 1e-3).all())
    # an approach start stands up to 2.5 m off, no nearer any other box than 0.6 m, facing
    # the box within 90 degrees, in the default start's pose
    assert bool((to_box[approaching] <= APPROACH_RANGE[1] + 0.01).all())
    others = (st.root_pos[:, None, :2] - env.resets.obj_rest[None, :, :2]).norm(dim=-1)
    others[ar, box] = 10.0
    assert bool((others[approaching].min(-1).values > 0.6).all())
    facing = torch.stack((yaw_of(st.root_quat).cos(), yaw_of(st.root_quat).sin()), -1)
    toward = (rest[:, :2] - st.root_pos[:, :2]) / to_box[:, None]
    assert bool(((facing * toward).sum(-1)[approaching] >= -1e-3).all())
    assert bool((st.dof_pos[approaching].abs() < 1e-5).all())
    hands = st.body_pos[:, env.index.hands]
    near = point_box_distance(hands, st.obj_pos[ar, box][:, None], st.obj_quat[ar, box][:, None],
                              env.index.obj_half[box][:, None]).max(-1).values
    tall = env.index.obj_half[box][:, 2] >= 0.3  # the oracle's reach pose cannot reach 0.5 m lids
    assert bool((near[at_box & tall] < GRASP_HAND_DIST).all())  # grasping is one action away
    ctx = env.context()
    assert bool((walk_to_box(ctx)[held] == 1.0).all()) and bool((hands_on_box(ctx)[held] == 1.0).all())
    # holding on keeps the box up, even with the pelvis asked lower than the legs allow (a
    # Follow policy asks for 0.5 m and stands at 0.93 m); letting go drops it
    a = torch.zeros(env.num_envs, env.num_actions)
    a[:, GRASP_ACTION], a[:, 35] = 1.0, -0.3
    for _ in range(20):
        env.step(a)
    kept = (env.episode_length_buf == 20) & held
    assert int(kept.sum()) >= env.num_envs // 3
    z = env.state.obj_pos[ar, box, 2]
    assert torch.allclose(z[kept], rest[kept, 2] + LIFT, atol=0.02)
    a[:, GRASP_ACTION] = -1.0
    for _ in range(20):
        env.step(a)
    assert bool((env.character.held_object() == -1).all())
    z = env.state.obj_pos[ar, box, 2]
    kept = (env.episode_length_buf == 40) & held
    assert bool((z[kept] < rest[kept, 2] + LIFT - 0.05).all())


def test_evaluation_and_the_default_never_start_holding() -> None:
    assert bool((_env(1.0, eval_mode=True).character.held_object() == -1).all())
    assert bool((_env(0.0).character.held_object() == -1).all())
    half = _env(0.5, n=64).character.held_object()
    assert 5 < int((half >= 0).sum()) < 30  # 0.5 x 0.45 of 64 = 14.4 expected


def test_a_character_that_cannot_hold_is_a_config_error(tmp_path: Path, capsys: pytest.CaptureFixture) -> None:
    rc = cli.main(["train", "carry", "--model", "mlp", "--runs", str(tmp_path), "--no-eval",
                   "env.character=humanoid", "env.mid_task_init_prob=0.25", "train.max_iterations=1"])
    err = capsys.readouterr().err
    assert rc == 2
    assert "env.mid_task_init_prob" in err and "humanoid" in err
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


def test_a_grasp_lets_go_only_well_below_zero() -> None:
    """Exploration noise around a positive grasp mean must not drop the box: with a release at
    0, a mean of 0.45 and std 0.3 let go at 7% of the steps; with a release at -0.5, the mean of
    0.1 that Carry starts from let go at 2.3% of the steps (held boxes fell within 1.4 s)."""
    env = _env(1.0, n=16)
    held = env.character.held_object() >= 0
    a = torch.zeros(env.num_envs, env.num_actions)
    a[:, GRASP_ACTION] = -0.7
    for _ in range(5):
        env.step(a)
    assert torch.equal(env.character.held_object() >= 0, held)
    a[:, GRASP_ACTION] = -1.0
    env.step(a)
    assert bool((env.character.held_object() == -1).all())


def test_training_success_counts_only_episodes_that_started_at_the_start() -> None:
    """A held start's grasp counts 0.5 from its first step, so its Carry success in the training
    log said nothing about learning to grasp; such episodes are left out of `Episode_Success/`
    (NaN values, which the training log skips; their terminations stay in
    `Episode_Termination/`)."""
    def logs(prob: float) -> list[dict]:
        cfg = resolve(CARRY, "mlp", ["env.character=puppet", f"env.mid_task_init_prob={prob}",
                                     "env.episode_length=5"])
        env = make_env(cfg, num_envs=8, verbose=False)
        a = torch.zeros(env.num_envs, env.num_actions)
        return [extras["log"] for extras in (env.step(a)[3] for _ in range(6)) if "episode_progress" in extras]

    every = logs(1.0)
    assert every and all("Episode_Termination/fell" in log for log in every)
    success = [v for log in every for k, v in log.items() if k.startswith("Episode_Success/")]
    assert success and all(bool(v.isnan().all()) for v in success)  # NaN: the training log skips them
    none = logs(0.0)
    assert none and all(len(log["Episode_Success/0_carry"]) == 8 for log in none)


def test_carrying_the_box_toward_its_destination_pays_at_any_distance() -> None:
    """`carry/box_to_target` pays the lifted box's velocity toward the destination (TokenHSI's
    carry reward): with position kernels alone, a box 5 m from its destination (LH1) earned
    exp(-12.5) for any motion. A box on the ground earns nothing for moving (no kicking)."""
    env = _env(1.0, n=32)
    ctx = env.context()
    lifted = box_lifted(ctx)
    toward = ctx.target[:, :2] - ctx.obj_pos[:, :2]
    far = toward.norm(dim=-1) > 1.0
    assert bool((lifted & far).any()) and bool((~lifted).any())
    toward = toward / toward.norm(dim=-1, keepdim=True)

    def paid(v: torch.Tensor) -> torch.Tensor:
        ctx.obj_lin = torch.cat((v, torch.zeros(len(v), 1)), -1)
        return env.rewards.compute(ctx)[1]["carry/box_to_target"]

    to, still, away = paid(1.5 * toward), paid(0.0 * toward), paid(-1.5 * toward)
    sel = lifted & far
    assert bool((to[sel] > still[sel] + 0.05).all()) and bool((still[sel] > away[sel]).all())
    sel = ~lifted & far
    assert torch.allclose(to[sel], still[sel])


def test_the_opt_in_lift_term_pays_the_height_above_rest_up_to_a_grasp() -> None:
    """`carry/box_lift` (weight 0 unless set): the box's rise as a share of `GRASP_LIFT`, so the
    last centimetres to a grasp pay as much as the first; 1 at the destination (setting the box
    down there costs nothing)."""
    off = _env(1.0, n=2)
    assert "carry/box_lift" not in off.rewards.compute(off.context())[1]
    env = _env(1.0, n=32, extra=("+rewards.terms.carry/box_lift=0.3",))
    ctx = env.context()
    away = (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1) > 0.5
    assert int(away.sum()) >= 16

    def paid(rise: torch.Tensor) -> torch.Tensor:
        ctx.obj_pos = torch.cat((ctx.obj_pos[:, :2], (ctx.obj_rest_z + rise)[:, None]), -1)
        return env.rewards.compute(ctx)[1]["carry/box_lift"]

    assert torch.allclose(paid(torch.full((32,), 0.5 * GRASP_LIFT))[away], torch.full((32,), 0.5)[away])
    assert torch.allclose(paid(torch.full((32,), LIFT)), torch.ones(32))
    assert torch.allclose(paid(torch.zeros(32))[away], torch.zeros(32)[away])
    ctx.obj_pos = ctx.target.clone()  # set down at the destination
    assert torch.allclose(env.rewards.compute(ctx)[1]["carry/box_lift"], torch.ones(32))


def test_carry_shows_the_box_as_its_target_until_it_is_carried_then_where_to_stand_to_set_it_down() -> None:
    env, ar, box, st, held = _started(32)
    spec = env.obs_spec
    newest = env.get_observations()["env"].reshape(env.num_envs, spec.env_steps, spec.env_dim)[:, -1]
    R = heading_matrix(yaw_of(st.root_quat))
    def shown(world: torch.Tensor) -> torch.Tensor:
        return ((world - st.root_pos)[:, None] @ R)[:, 0]
    destination = torch.tensor(env.plan[0].fixed_target).expand(env.num_envs, 3).clone()
    # a held box's goal: where the pelvis stands when it walked there facing the destination
    # with the box in front of it, the box on the destination
    reach = (st.root_pos[:, :2] - st.obj_pos[ar, box, :2]).norm(dim=-1, keepdim=True)
    back = st.obj_pos[ar, box, :2] - destination[:, :2]
    destination[:, :2] += reach * back / back.norm(dim=-1, keepdim=True)
    target, path = newest[:, spec.env_fields()["target"]], newest[:, spec.env_fields()["path"]]
    assert torch.allclose(target[held], shown(destination)[held], atol=1e-4)
    assert torch.allclose(target[~held], shown(st.obj_pos[ar, box])[~held], atol=1e-4)
    assert torch.allclose(path[~held, :2], shown(st.obj_pos[ar, box])[~held, :2], atol=1e-4)  # path points too


def test_a_carried_boxs_goal_stays_put_while_the_character_turns_and_walks() -> None:
    """Attempt 14's defect: the goal was the destination plus the pelvis-to-box offset now,
    which turns with the heading; a Follow policy chased it round in circles ~1 m away."""
    env, ar, box, st, held = _started(32)
    first = env.context().goal.clone()
    actions = torch.zeros(env.num_envs, env.num_actions)
    actions[:, 32], actions[:, 34], actions[:, GRASP_ACTION] = 0.5, 0.8, 1.0  # walk on a curve, hold
    for _ in range(15):
        env.step(actions)
    ctx = env.context()
    still = held & (env.character.held_object() >= 0) & (env.episode_length_buf > 0)
    assert int(still.sum()) >= 8
    turned = (yaw_of(ctx.state.root_quat) - yaw_of(st.root_quat)).abs()
    assert bool((turned[still] > 0.5).all())
    assert torch.allclose(ctx.goal[still], first[still], atol=1e-5)


def test_a_grasp_is_taken_only_where_the_skill_holds_objects() -> None:
    """The puppet's grasp serves Carry alone: a Climb policy that could grasp lifted the box it
    was to climb and flew it away (the climb point moves with the box)."""
    env, ar, box, st, held = _started(48)
    hands = st.body_pos[:, env.index.hands]
    near = point_box_distance(hands, st.obj_pos[ar, box][:, None], st.obj_quat[ar, box][:, None],
                              env.index.obj_half[box][:, None]).max(-1).values < GRASP_HAND_DIST
    reachable = ~held & near
    assert int(reachable.sum()) >= 2
    a = torch.zeros(env.num_envs, env.num_actions)
    a[:, GRASP_ACTION] = 1.0
    refuse = torch.zeros(env.num_envs, dtype=torch.bool)
    refuse[torch.nonzero(reachable).flatten()[::2]] = True
    env.character.pre_step(a, st, ~refuse)
    now = env.character.held_object() >= 0
    assert not bool(now[refuse].any())                   # refused, and held boxes let go
    assert bool(now[reachable & ~refuse].all())          # taken where the skill holds
    assert torch.equal(now[held & ~refuse], held[held & ~refuse])


def test_climb_mid_task_starts_stand_beside_the_object_facing_it() -> None:
    """Climb's mid-task starts (where LH1's Climb begins, beside the box Carry put down): every
    start 0.2-1.0 m beyond the box's half diagonal, on every side, facing it within 90 degrees,
    the free box where it rests; they step without falling through anything."""
    from detach.skills.climb import NEAR_RANGE

    box = ['scene[0].category=Box', 'scene[0].model_id=box_060x060x070', 'scene[0].size=[0.6,0.6,0.7]',
           'scene[0].pos3d=[2.5,0.0,0.35]', 'scene[0].static=false', 'scene[0].mass=5.0']
    cfg = resolve(ROOT / "configs/tasks/climb.yaml", "mlp",
                  ["env.character=puppet", "env.mid_task_init_prob=1.0", *box])
    env = make_env(cfg, num_envs=24, verbose=False)
    st, centre = env.state, torch.tensor([2.5, 0.0])
    away = st.root_pos[:, :2] - centre
    dist = away.norm(dim=-1)
    diagonal = float(torch.tensor([0.3, 0.3]).norm())
    assert bool(env.tracker.started_mid_task.all())
    assert bool((dist >= diagonal + NEAR_RANGE[0] - 1e-3).all())
    assert bool((dist <= diagonal + NEAR_RANGE[1] + 1e-3).all())
    sides = torch.atan2(away[:, 1], away[:, 0])
    assert {int(q) for q in ((sides + torch.pi) // (torch.pi / 2)).clamp(max=3).tolist()} == {0, 1, 2, 3}
    facing = torch.stack((yaw_of(st.root_quat).cos(), yaw_of(st.root_quat).sin()), -1)
    assert bool(((facing * -away / dist[:, None]).sum(-1) >= -1e-3).all())
    assert torch.allclose(st.obj_pos[:, 0], torch.tensor([2.5, 0.0, 0.35]).expand(24, 3), atol=1e-3)
    assert not bool((env.character.held_object() >= 0).any())
    for _ in range(30):
        _obs, rew, _dones, _ = env.step(torch.zeros(24, env.num_actions))
    assert bool(torch.isfinite(rew).all()) and float(env.state.root_pos[:, 2].min()) > 0.5


def test_sit_mid_task_starts_sit_on_or_stand_near_a_raised_seat() -> None:
    """Sit's mid-task starts at LH1's chair on its 1 m platform: a share seated at the sit point
    (they stay there), the rest standing on the highest surface under them (the platform, or the
    floor beyond its edge) at the standing height above it, 0.2-1.5 m beyond the chair's half
    diagonal, facing the sit point within 45 degrees; all step without falling through anything.
    Without them a puppet reached the raised seat only by hovering a metre above it, where the
    seat term pays nothing."""
    from detach.skills.sit import NEAR_RANGE, NEAR_YAW_NOISE, SEATED_SHARE

    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "mlp",
                  ["env.character=puppet", "env.mid_task_init_prob=1.0", "plan=[sit]", "target_object=[1]",
                   "sample_target_from=[scene_1]"])
    env = make_env(cfg, num_envs=48, verbose=False)
    st, ctx = env.state, env.context()
    assert bool(env.tracker.started_mid_task.all())
    seated = ctx.dist < 0.05
    assert 0.1 < float(seated.float().mean()) < 2 * SEATED_SHARE
    away = st.root_pos[:, :2]                                      # the chair stands at (0, 0)
    dist, diagonal = away.norm(dim=-1), float(torch.tensor([0.275, 0.275]).norm())
    standing = ~seated
    assert bool((dist[standing] >= diagonal + NEAR_RANGE[0] - 1e-3).all())
    assert bool((dist[standing] <= diagonal + NEAR_RANGE[1] + 1e-3).all())
    surface = st.root_pos[:, 2] - START_HEIGHT
    on_platform = standing & (away[:, 0].abs() < 2.3) & (away[:, 1].abs() < 1.3)
    assert bool(on_platform.any()) and bool((standing & ~on_platform).any())
    assert torch.allclose(surface[on_platform], torch.ones(int(on_platform.sum())), atol=1e-3)
    to_seat = ctx.target[:, :2] - away
    facing = torch.stack((yaw_of(st.root_quat).cos(), yaw_of(st.root_quat).sin()), -1)
    cos = (facing * to_seat).sum(-1) / to_seat.norm(dim=-1)
    assert bool((cos[standing] >= torch.cos(torch.tensor(NEAR_YAW_NOISE)) - 1e-3).all())
    for _ in range(30):
        _obs, rew, _dones, _ = env.step(torch.zeros(48, env.num_actions))
    assert bool(torch.isfinite(rew).all())
    assert bool((env.state.root_pos[on_platform, 2] > 1.0 + 0.5).all())  # still on the platform, not in it
    assert bool((env.context().dist[seated] < cfg.env.success_threshold).all())  # the seat holds them
