"""Sit: sit on an object's seat (the paper's "Sit").

Target: `scene_K` (object K's sit point, `tarSitPos` of its asset: 0.1 m above the seat,
carried into the world by the object's current pose) or a fixed `tarpos_K`. Distance: 3-D
from the pelvis to the target. Rewards: `approach` and the `seat` kernel; an opt-in sharper
kernel on the same distance (`seat_precision`, weight 0). Success (the paper: "the pelvis on
the upper surface of the target object"): the transition fired.

Mid-task starts (`env.mid_task_init_prob`): a share `SEATED_SHARE` seated, in the oracle's
sitting pose at the sit point (TokenHSI starts some Sit episodes from sitting clips), the rest
standing near the seat on whatever surface is there (the floor, or the platform a raised
chair stands on). The seat term pays exp(-10 d^2), nothing beyond ~1 m: a puppet that reached
LH1's chair on its 1 m platform by hovering at its root servo's top, 1 m above the sit point,
was paid by `approach` alone and never came down, from standing starts near the seat too.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from detach.character.body import NUM_DOF, START_HEIGHT
from detach.skills.base import MidTaskStart, RewardTerm, Skill, Subtask
from detach.skills.climb import object_point_world, object_points
from detach.skills.context import OracleCommand, SkillContext
from detach.skills.kernels import approach, uniform_draw
from detach.skills.registry import register_skill
from detach.skills.scripting import hinge_pose
from detach.torch_math import quat_from_yaw, wrap_angle

SIT_POSE = hinge_pose(right_hip_y=-1.57, left_hip_y=-1.57, right_shoulder_y=-1.2, left_shoulder_y=-1.2)
"""The oracle's long sitting: thighs and shins straight forward, arms reaching forward."""


NEAR_RANGE = (0.2, 1.5)
"""A mid-task start stands this far (m) beyond the object's XY half diagonal from its centre."""
NEAR_YAW_NOISE = math.pi / 4
"""...facing the sit point give or take this (rad)."""
SEATED_SHARE = 0.3
"""Share of the mid-task starts seated at the sit point, the rest standing near the seat."""
FOOTPRINT = 0.2
"""A start stands on the highest surface within this radius (m) of its pelvis, feet clear."""
DESCENT = (0.04, 0.5)
"""The oracle comes down from above the seat to it as its pelvis closes from 0.5 to 0.04 m (XY)
of the sit point, its height command continuous in that distance. Why: a policy taught by the
oracle (`train.teachers.sit=oracle`) matches it to a few centimetres, not to the millimetre;
with a step at 0.04 m such a policy hovered 0.75 m above LH1's seat 5 cm off its centre, and
with the descent over 0.2-0.04 m, 0.5-0.6 m above it (its height action stayed the one of the
approach, where the oracle rises)."""


def descent_height(dxy: torch.Tensor, seat_z: torch.Tensor, above_z: torch.Tensor) -> torch.Tensor:
    """The oracle's pelvis height command at XY distance dxy from the sit point: `above_z`
    (clear of everything around the seat) from `DESCENT[1]` out, `seat_z` within `DESCENT[0]`,
    linear between."""
    lo, hi = DESCENT
    return seat_z + (above_z - seat_z) * ((dxy - lo) / (hi - lo)).clamp(0.0, 1.0)


def sit_approach(ctx: SkillContext) -> torch.Tensor:
    return approach(ctx, ctx.target)


def seat(ctx: SkillContext) -> torch.Tensor:
    return torch.exp(-10.0 * ctx.dist ** 2)


def seat_precision(ctx: SkillContext) -> torch.Tensor:
    """exp(-50 d^2) of the pelvis's 3-D distance to the sit point: `seat` pays 0.46 at the
    0.3 m success threshold and changes little within it, and puppets that reached LH1's
    raised chair settled on the seat's rim 0.27-0.45 m from the sit point, half of them outside
    the threshold; this kernel pays 0.01 there and 0.61 at 0.1 m. Weight 0 unless
    `+rewards.terms.sit/seat_precision=W` sets one."""
    return torch.exp(-50.0 * ctx.dist ** 2)


@register_skill
class Sit(Skill):
    name = "sit"
    display_name = "Sit"
    color = (148, 103, 189)
    motion_labels = ("sit", "walk")
    sources = ("scene", "tarpos")
    needs_object = True
    mid_task_reads_target = False
    reward_terms = {"approach": RewardTerm(sit_approach, 0.3), "seat": RewardTerm(seat, 0.7),
                    "seat_precision": RewardTerm(seat_precision, 0.0)}

    def bind(self, plan, services) -> None:
        super().bind(plan, services)
        self.local = object_points(services.scene, "tar_sit_local", self.device)
        self._object_headings: torch.Tensor | None = None
        self._plan_obj = torch.tensor([max(sub.obj, 0) for sub in self.plan], device=self.device)
        """Each subtask's object (0 where it has none), for the oracle's sitting direction."""
        objects = services.scene.objects
        self.seat_rest = torch.tensor(np.array([o.tar_sit_world for o in objects], dtype=np.float32).reshape(-1, 3),
                                      device=self.device)
        """Each object's sit point where it rests (world), indexed by object."""
        self.rest_yaw = torch.tensor([o.z_rot for o in objects], dtype=torch.float32, device=self.device)

    def display_target(self, sub: Subtask, scene) -> np.ndarray | None:
        if sub.fixed_target is None and sub.obj >= 0:
            return scene.objects[sub.obj].to_world(scene.objects[sub.obj].tar_sit_local)
        return super().display_target(sub, scene)

    def target(self, ctx: SkillContext) -> torch.Tensor:
        return torch.where(ctx.has_fixed[:, None], ctx.fixed_target, object_point_world(ctx, self.local))

    def mid_task_start(self, objects, obj_rest, obj_half, target, gen) -> MidTaskStart:
        """Seated at the sit point in the oracle's sitting pose, facing the oracle's sitting
        direction (`SEATED_SHARE`), or standing near the object, on any side, on the highest
        surface under the feet, facing the sit point within `NEAR_YAW_NOISE`; the object where
        it rests."""
        n, dev = len(obj_rest), obj_rest.device

        def uniform(lo: float, hi: float) -> torch.Tensor:
            return uniform_draw(n, lo, hi, gen, dev)

        side, gap, turn = uniform(-math.pi, math.pi), uniform(*NEAR_RANGE), uniform(-NEAR_YAW_NOISE, NEAR_YAW_NOISE)
        seated = uniform(0, 1) < SEATED_SHARE
        seat = self.seat_rest[objects]
        reach = obj_half[:, :2].norm(dim=-1) + gap
        near_xy = obj_rest[:, :2] + torch.stack((side.cos(), side.sin()), -1) * reach[:, None]
        to_seat = seat[:, :2] - near_xy
        near_yaw = torch.atan2(to_seat[:, 1], to_seat[:, 0]) + turn
        root_xy = torch.where(seated[:, None], seat[:, :2], near_xy)
        yaw = wrap_angle(torch.where(seated, self.object_headings()[objects], near_yaw))
        ground = self.services.raster.highest_within(near_xy, FOOTPRINT, directions=8)
        height = torch.where(seated, seat[:, 2], ground + START_HEIGHT)
        hinges = torch.where(seated[:, None], SIT_POSE.to(dev), torch.zeros(n, NUM_DOF, device=dev))
        return MidTaskStart(root_xy, yaw, height, hinges, obj_rest.clone(), quat_from_yaw(self.rest_yaw[objects]),
                            held=torch.zeros(n, dtype=torch.bool, device=dev))

    # ------------------------------------------------------------------ oracle
    def object_headings(self) -> torch.Tensor:
        """[K] the yaw (rad) the oracle sits facing on each scene object (`_sit_heading`),
        computed on first use."""
        if self._object_headings is None:
            self._object_headings = torch.tensor([self._sit_heading(k) for k in range(len(self.seat_rest))],
                                                 dtype=torch.float32, device=self.device)
        return self._object_headings

    def _sit_heading(self, obj: int) -> float:
        """Yaw (rad) to sit on object obj facing a direction whose leg line is free."""
        raster, dev = self.services.raster, self.device
        o = self.services.scene.objects[obj]
        seat_pt = torch.as_tensor(o.tar_sit_world, dtype=torch.float32, device=dev)
        base = o.z_rot + math.pi / 2  # the object faces its local +Y
        best, best_h = base, float("inf")
        for k in (0, 1, 3, 2):
            yaw = base + k * math.pi / 2
            t = torch.linspace(0.25, 1.0, 16, device=dev)
            pts = seat_pt[:2] + t[:, None] * torch.tensor([math.cos(yaw), math.sin(yaw)], device=dev)
            h = float(raster.sample(pts).max())
            if h <= seat_pt[2] - 0.1 + 0.03:
                return yaw
            if h < best_h:
                best, best_h = yaw, h
        return best

    def _clearance(self, frm: torch.Tensor, to: torch.Tensor) -> torch.Tensor:
        """Highest static surface (m) along segments frm -> to [n, 2] and within 1 m of `to`."""
        dev = self.device
        t = torch.linspace(0.0, 1.0, 24, device=dev)
        line = frm[:, None] + t[None, :, None] * (to - frm)[:, None]
        ang = torch.linspace(0, 2 * math.pi, 13, device=dev)[:-1]
        ring = torch.cat([to[:, None] + r * torch.stack((ang.cos(), ang.sin()), -1)[None] for r in (0.4, 0.8, 1.05)], 1)
        return self.services.raster.sample(torch.cat((line, ring), 1)).max(dim=-1).values

    def oracle(self, ctx: SkillContext, cmd: OracleCommand, active: torch.Tensor) -> None:
        """Take a long-sitting pose facing the first of the object's facing direction and its
        90/180 deg turns whose leg line is free, rise above everything around the seat, move
        over the sit point and lower onto the seat on the way in (`DESCENT`)."""
        p, target = ctx.state.root_pos, ctx.target
        pxy = p[:, :2]
        dxy = (target[:, :2] - pxy).norm(dim=-1)
        far = dxy > 2.0
        clear = self._clearance(pxy, target[:, :2]) + 0.2
        up = p[:, 2] > clear - 0.05
        vs = (2.5 * (target[:, :2] - pxy)).clamp(-1.2, 1.2)
        vs = torch.where((far | up | (dxy < DESCENT[1]))[:, None], vs, torch.zeros_like(vs))
        cmd.velocity = torch.where(active[:, None], vs, cmd.velocity)
        heading = self.object_headings()[self._plan_obj[ctx.subtask]]
        cmd.yaw_target = torch.where(active & far, torch.atan2(vs[:, 1], vs[:, 0]),
                                     torch.where(active, heading, cmd.yaw_target))
        zs = descent_height(dxy, target[:, 2] - 0.1, torch.maximum(clear, cmd.height))
        cmd.height = torch.where(active & ~far, zs, cmd.height)
        cmd.hinges = torch.where((active & ~far)[:, None], SIT_POSE.to(self.device), cmd.hinges)
