"""Carry: pick up a box and put it down at a destination (the paper's "Carry").

Plan entry: `target_object` names the box (a dynamic object), `tarpos_K` its destination.
Distance: 3-D from the box's bbox centre to the destination. Success (the paper): 1 when
delivered (the transition fired), 0.5 when the box was only grasped (lifted at least
`GRASP_LIFT` above its resting height), else 0. Rewards: walk to the box, hands on the box,
hold it up, bring it to the destination (position and velocity toward it, as TokenHSI's).
"""

from __future__ import annotations

import math

import torch

from detach.character.body import BODY_NAMES, HANDS, START_HEIGHT
from detach.skills.base import MidTaskStart, PlanError, RewardTerm, Skill, Subtask
from detach.skills.context import OracleCommand, SkillContext
from detach.skills.kernels import NEAR, approach, approach_velocity, uniform_draw
from detach.skills.registry import register_skill
from detach.skills.scripting import hinge_index
from detach.torch_math import index_on, point_box_distance, quat_from_yaw, quat_rotate, wrap_angle

GRASP_LIFT = 0.1
"""A box counts as grasped once lifted this far (m) above its resting height."""
LIFT = 0.2
"""How far (m) the oracle raises a grasped box."""
HELD_YAW_NOISE = 0.5
"""A held start faces the destination within +- this (rad)."""
APPROACH_SHARE = 0.4
"""Share of the mid-task starts standing (in the default start's pose) `APPROACH_RANGE` from the
box, on the destination's side of it, not facing it exactly (`APPROACH_YAW_NOISE`)."""
APPROACH_RANGE = (0.8, 2.5)
"""Distance (m) of an approach start's pelvis from the box's centre, uniform, at most the
box's distance from its destination."""
APPROACH_SPREAD = math.pi / 4
"""An approach start stands within +- this (rad) of the line from the box to its destination:
on the nine-box ring, further round would stand in the neighbouring box."""
APPROACH_YAW_NOISE = math.pi / 2
"""An approach start faces the box within +- this (rad)."""
PICK_UP_SHARE = 0.15
"""Share of the mid-task starts at the box, hands on its lid, not yet grasped. The rest
(0.45) start holding it. TokenHSI's box clips start 1 in 4 at the pick-up (pick up 0.1,
carry 0.3); ours give the pick-up and the approach together the larger share."""


def box_lifted(ctx: SkillContext) -> torch.Tensor:
    """[N] bool: the subtask's box is at least `GRASP_LIFT` above its resting height."""
    return ctx.obj_pos[:, 2] >= ctx.obj_rest_z + GRASP_LIFT


def box_at_destination(ctx: SkillContext) -> torch.Tensor:
    """[N] bool: the subtask's box is within `NEAR` (XY) of its destination."""
    return (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1) < NEAR


def walk_to_box(ctx: SkillContext) -> torch.Tensor:
    """Walk to the box; 1 once the box is lifted or at the destination (each later stage of
    the task pays the earlier stages' terms in full: a box held in front of the pelvis is
    more than `NEAR` away from it)."""
    r = approach(ctx, ctx.obj_pos)
    return torch.where(box_at_destination(ctx) | box_lifted(ctx), torch.ones_like(r), r)


HAND_IDS = tuple(BODY_NAMES.index(h) for h in HANDS)


def hands_on_box(ctx: SkillContext) -> torch.Tensor:
    """exp(-20 d^2) of the hands' mean distance d to the box's surface; 1 while the box is
    lifted. Ours (TokenHSI's humanoid needs no such term: its hands close on the box by
    contact); it makes the grasp, which needs both hands on the box, findable by exploration."""
    hands = ctx.state.body_pos[:, index_on(HAND_IDS, ctx.state.body_pos.device)]
    d = point_box_distance(hands, ctx.obj_pos[:, None], ctx.obj_quat[:, None], ctx.obj_half[:, None]).mean(-1)
    return torch.where(box_lifted(ctx), torch.ones_like(d), torch.exp(-20.0 * d * d))


def box_height(ctx: SkillContext) -> torch.Tensor:
    far = (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1) > NEAR
    goal = torch.where(far, ctx.obj_rest_z + 0.3, ctx.target[:, 2])
    return torch.exp(-10.0 * (ctx.obj_pos[:, 2] - goal) ** 2)


def box_lift(ctx: SkillContext) -> torch.Tensor:
    """The box's height above its rest as a share of `GRASP_LIFT` (clipped to [0, 1]); 1 once
    the box is near its destination, where it is to be put down. Ours, opt-in (weight 0 unless
    `+rewards.terms.carry/box_lift=W`): `box_height`'s kernel pays 0.54 at 5 cm and 0.67 at
    10 cm, so a policy that holds the box at standing height earns little for the last
    centimetres to a grasp; this term pays them linearly."""
    share = ((ctx.obj_pos[:, 2] - ctx.obj_rest_z) / GRASP_LIFT).clamp(0.0, 1.0)
    return torch.where(box_at_destination(ctx), torch.ones_like(share), share)


def box_to_target(ctx: SkillContext) -> torch.Tensor:
    """Bring the box to its destination, in TokenHSI's proportions: a wide XY kernel (1/4) and
    the box's velocity toward the destination (1/4; `approach_velocity`), both paid only while
    the box is lifted or near the destination so that kicking it along pays nothing, and a
    narrow 3-D kernel (1/2). The velocity term is what pays at any distance: a box 5 m from its
    destination (LH1) earns exp(-12.5) from the wide kernel."""
    d_xy = (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1)
    d3 = (ctx.obj_pos - ctx.target).norm(dim=-1)
    far = 0.5 * torch.exp(-0.5 * d_xy * d_xy) + 0.5 * approach_velocity(ctx.obj_lin, ctx.obj_pos, ctx.target)
    carried = box_lifted(ctx) | (d_xy < NEAR)
    return 0.5 * torch.where(carried, far, torch.zeros_like(far)) + 0.5 * torch.exp(-5.0 * d3 * d3)


def reach_pose(top_z: torch.Tensor, pelvis_z: float = START_HEIGHT) -> tuple[torch.Tensor, torch.Tensor]:
    """Hinge targets [n, 32] that put both hands 2 cm above a lid at height top_z [n] (m), and
    the hands' forward reach (m) from the pelvis at height pelvis_z.

    The torso pitches forward by phi (abdomen_y; more for low lids) and the straight arms
    (0.53 m from shoulder to hand) hang at beta from the vertical, solved from the shoulder's
    height; the shoulder hinge is -(beta + phi) because it rotates with the torso.
    """
    phi = torch.where(top_z < 0.85, torch.full_like(top_z, 0.9), torch.full_like(top_z, 0.4))
    sx = -0.01 * torch.cos(phi) + 0.25 * torch.sin(phi)
    sz = pelvis_z + 0.12 + 0.01 * torch.sin(phi) + 0.25 * torch.cos(phi)
    arm = 0.53
    cosb = ((sz - (top_z + 0.02)) / arm).clamp(-1.0, 1.0)
    beta = torch.acos(cosb).clamp(0.0, 1.5)
    q = torch.zeros(len(top_z), 32, device=top_z.device)
    q[:, hinge_index("abdomen_y")] = phi
    q[:, hinge_index("right_shoulder_y")] = -beta - phi
    q[:, hinge_index("left_shoulder_y")] = -beta - phi
    return q, sx + arm * torch.sin(beta)


@register_skill
class Carry(Skill):
    name = "carry"
    display_name = "Carry"
    color = (255, 127, 14)
    motion_labels = ("carry", "walk")
    sources = ("tarpos",)
    needs_object = True
    holds_objects = True
    stats = {"grasped": torch.bool}
    reward_terms = {"walk_to_box": RewardTerm(walk_to_box, 0.2), "hands_on_box": RewardTerm(hands_on_box, 0.1),
                    "box_height": RewardTerm(box_height, 0.2), "box_to_target": RewardTerm(box_to_target, 0.5),
                    "box_lift": RewardTerm(box_lift, 0.0)}

    def compile_entry(self, index, source, ref, obj, task) -> Subtask:
        if source == "scene":
            raise PlanError(("sample_target_from", index), "scene_K names the box itself, which gives no "
                            "destination; use tarpos_K")
        sub = super().compile_entry(index, source, ref, obj, task)
        if task.scene[obj].static:
            raise PlanError(("target_object", index), f"'carry' needs a dynamic object, but scene[{obj}] "
                            f"({task.scene[obj].name}) is static")
        return sub

    def bind(self, plan, services) -> None:
        super().bind(plan, services)
        objects = services.scene.objects
        self.dyn_slot = torch.full((max(len(objects), 1),), -1, dtype=torch.long, device=self.device)
        for k, i in enumerate(services.scene.dynamic):
            self.dyn_slot[i] = k
        self.carry_goal = torch.zeros(services.num_envs, 2, device=self.device)
        """[N, 2] where each env's pelvis takes the box (`goal`), fixed when the carry began."""
        self.carrying = torch.zeros(services.num_envs, dtype=torch.bool, device=self.device)
        """[N] bool: the box was carried at the last `goal` call."""

    def distance(self, ctx: SkillContext) -> torch.Tensor:
        return (ctx.obj_pos - ctx.target).norm(dim=-1)

    def goal(self, ctx: SkillContext) -> torch.Tensor:
        """The box until it is carried (lifted, held by the character or near the
        destination); from then on a fixed point: the destination moved toward where the box
        was taken by the pelvis-to-box distance at that moment (XY; the destination's height),
        where the pelvis stands when it walked there facing the destination with the box held
        in front. Ours: the policy sees the box and the destination either way; showing the
        place to walk to now in the target that Follow walks to lets a Follow policy walk to
        the box and carry it home without learning a new input first. The point stays put
        while the box is carried: a goal that moves with the pelvis (the destination plus the
        current pelvis-to-box offset, which turns with the heading) was chased round in circles
        about 1 m from it (results/laptop/NOTEBOOK.md, attempt 14)."""
        carrying = box_lifted(ctx) | box_at_destination(ctx) | self.held(ctx)
        reach = (ctx.state.root_pos[:, :2] - ctx.obj_pos[:, :2]).norm(dim=-1, keepdim=True)
        back = ctx.obj_pos[:, :2] - ctx.target[:, :2]
        back = back / back.norm(dim=-1, keepdim=True).clamp(min=1e-6)
        taken = carrying & ~self.carrying
        self.carry_goal = torch.where(taken[:, None], ctx.target[:, :2] + reach * back, self.carry_goal)
        self.carrying = carrying
        goal = torch.cat((self.carry_goal, ctx.target[:, 2:]), -1)
        return torch.where(carrying[:, None], goal, ctx.obj_pos)

    def held(self, ctx: SkillContext) -> torch.Tensor:
        """[N] bool: the character holds the subtask's box by its grasp constraint."""
        slot = self.dyn_slot[ctx.obj.clamp(min=0)]
        return (ctx.held == slot) & (slot >= 0)

    def start(self, mask: torch.Tensor, subtask: torch.Tensor, root_xy: torch.Tensor) -> None:
        self.carrying &= ~mask

    def mid_task_start(self, objects, obj_rest, obj_half, target, gen) -> MidTaskStart:
        """One of three starts, drawn per episode: (`APPROACH_SHARE`) standing some way from the
        box, turned partly away from it; (`PICK_UP_SHARE`) at the box, in the oracle's reach
        pose with the hands on its resting lid, not yet holding it; or (the rest) the box
        carried part of the way: lifted `LIFT`, held in the reach pose at a uniform point of
        the way from its resting place to the destination, facing the destination. The pelvis
        is at the standing height (where it stands on its legs whatever lower height it asks for).

        TokenHSI starts a quarter of its Carry episodes from reference clips of picking up,
        carrying and putting down a box; without a walk-to-box-and-grasp success first, a
        policy never sees what holding and carrying pay. We have no box clips, so the states
        are built from the oracle's geometry. The approach starts are ours: from the default
        start (2.5 m away, facing anywhere) walking to the box is paid only by `walk_to_box`,
        and no policy learned it there (results/laptop/NOTEBOOK.md, "Carry"); nearer starts
        reach the pick-up, whose rewards are larger, by walking a little.
        """
        n, dev = len(obj_rest), obj_rest.device

        def uniform(lo: float, hi: float) -> torch.Tensor:
            return uniform_draw(n, lo, hi, gen, dev)

        u, noise, draw = uniform(0, 1), uniform(-HELD_YAW_NOISE, HELD_YAW_NOISE), uniform(0, 1)
        side, dist, turn = uniform(-APPROACH_SPREAD, APPROACH_SPREAD), uniform(*APPROACH_RANGE), \
            uniform(-APPROACH_YAW_NOISE, APPROACH_YAW_NOISE)
        approaching = draw < APPROACH_SHARE
        held = draw >= APPROACH_SHARE + PICK_UP_SHARE
        u = torch.where(held, u, torch.zeros_like(u))
        lift = torch.where(held, torch.full_like(u, LIFT), torch.zeros_like(u))
        route = target[:, :2] - obj_rest[:, :2]
        heading = torch.atan2(route[:, 1], route[:, 0])
        box_xy = obj_rest[:, :2] + u[:, None] * route
        yaw = heading + noise
        hinges, reach = reach_pose(obj_rest[:, 2] + obj_half[:, 2] + lift)
        ahead = reach + (obj_half[:, 0] - 0.15).clamp(min=0.05)
        root_xy = box_xy - torch.stack((yaw.cos(), yaw.sin()), -1) * ahead[:, None]
        # approach: out from the box toward the destination (turned by `side`), facing back
        out = heading + side
        away = torch.minimum(dist, route.norm(dim=-1))
        stand = obj_rest[:, :2] + torch.stack((out.cos(), out.sin()), -1) * away[:, None]
        root_xy = torch.where(approaching[:, None], stand, root_xy)
        yaw = torch.where(approaching, wrap_angle(out + math.pi + turn), yaw)
        hinges = torch.where(approaching[:, None], torch.zeros_like(hinges), hinges)
        box = torch.cat((box_xy, (obj_rest[:, 2] + lift)[:, None]), -1)
        return MidTaskStart(root_xy, yaw, torch.full((n,), START_HEIGHT, device=dev), hinges,
                            box, quat_from_yaw(heading + torch.where(approaching, 0.0, noise)), held=held)

    def update_stats(self, ctx, active, stats) -> None:
        ar = torch.arange(ctx.num_envs, device=self.device)
        stats["grasped"][ar, ctx.subtask] |= active & box_lifted(ctx)

    def score(self, done, stats) -> torch.Tensor:
        grasped = stats["grasped"]
        return torch.where(done, torch.ones_like(grasped, dtype=torch.float32), 0.5 * grasped.float())

    def oracle(self, ctx: SkillContext, cmd: OracleCommand, active: torch.Tensor) -> None:
        """Walk to the box face opposite its destination (via a point in front of that face),
        bend over until both hands rest on the lid, grasp, lift `LIFT`, translate (without
        turning) until the box is 0.1 m short of the destination, lower it, and hold."""
        n, dev = ctx.num_envs, self.device
        box, bq, half, target = ctx.obj_pos, ctx.obj_quat, ctx.obj_half, ctx.target
        pxy, yaw = ctx.state.root_pos[:, :2], cmd.yaw
        held = self.held(ctx)
        # the box face whose outward normal points away from the destination
        away = box[:, :2] - target[:, :2]
        axes = torch.stack((quat_rotate(bq, torch.tensor([1.0, 0, 0], device=dev).expand(n, 3)),
                            quat_rotate(bq, torch.tensor([0, 1.0, 0], device=dev).expand(n, 3))), 1)[..., :2]
        axes = axes / axes.norm(dim=-1, keepdim=True).clamp(min=1e-6)
        cand = torch.cat((axes, -axes), 1)  # [n, 4, 2]: +x, +y, -x, -y
        hd = torch.cat((half[:, :2], half[:, :2]), 1)  # half depth along each normal
        k = (cand * away[:, None]).sum(-1).argmax(-1)
        ar = torch.arange(n, device=dev)
        normal, depth = cand[ar, k], hd[ar, k]
        top = box[:, 2] + half[:, 2]
        q_reach, reach = reach_pose(top)
        stand = box[:, :2] + normal * (reach + (depth - 0.15).clamp(min=0.05))[:, None]
        via = stand + normal * 0.6
        d_stand = (stand - pxy).norm(dim=-1)
        goal = torch.where((d_stand > 0.7)[:, None], via, stand)
        # walk around the box (on a circle) until in front of the chosen face
        rel = pxy - box[:, :2]
        th_p, th_n = torch.atan2(rel[:, 1], rel[:, 0]), torch.atan2(normal[:, 1], normal[:, 0])
        dth = wrap_angle(th_n - th_p)
        radius = (half[:, :2].norm(dim=-1) + 0.5).clamp(min=rel.norm(dim=-1).clamp(max=3.0))
        th = th_p + dth.sign() * 0.6
        orbit = box[:, :2] + radius[:, None] * torch.stack((th.cos(), th.sin()), -1)
        goal = torch.where((dth.abs() > 0.4)[:, None], orbit, goal)
        v_app = (2.5 * (goal - pxy)).clamp(-1.5, 1.5)
        face = torch.atan2(-normal[:, 1], -normal[:, 0])
        arrived = (d_stand < 0.06) & (wrap_angle(face - yaw).abs() < 0.1)
        # carrying: translate so that the box ends 0.1 m short of the destination
        to_dest = target[:, :2] - box[:, :2]
        dd = to_dest.norm(dim=-1)
        goal_box = target[:, :2] - to_dest / dd.clamp(min=1e-6)[:, None] * 0.1
        v_carry = (2.0 * (goal_box - box[:, :2]))
        v_carry = v_carry * (1.4 / v_carry.norm(dim=-1, keepdim=True).clamp(min=1.4))
        at_dest = (goal_box - box[:, :2]).norm(dim=-1) < 0.05
        delivered = ((box - target).norm(dim=-1) <= self.services.cfg.env.success_threshold) & ~held
        vm = torch.where(held[:, None], v_carry, torch.where(delivered[:, None], torch.zeros_like(v_app), v_app))
        cmd.velocity = torch.where(active[:, None], vm, cmd.velocity)
        cmd.yaw_target = torch.where(active & ~held & (d_stand < 1.5), face, cmd.yaw_target)
        cmd.yaw_target = torch.where(active & ~held & (d_stand >= 1.5), torch.atan2(v_app[:, 1], v_app[:, 0]),
                                     cmd.yaw_target)
        z_c = torch.where(held & ~at_dest, cmd.height + LIFT, cmd.height)
        cmd.height = torch.where(active, z_c, cmd.height)
        near = active & (d_stand < 0.4)
        cmd.hinges = torch.where((near | held)[:, None], q_reach, cmd.hinges)
        cmd.grasp = torch.where(active & ((arrived & ~delivered) | held), torch.ones_like(cmd.grasp), cmd.grasp)

