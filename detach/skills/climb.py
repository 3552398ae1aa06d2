"""Climb: get onto an object and stand on it (the paper's "Climb").

Target: `scene_K` (object K's climb point, `tarClimbPos` of its asset: the top surface above
the bbox centre, carried into the world by the object's current pose, its height that of the
object's current top: `object_top_point`) raised by `env.climb_pelvis_height` (a standing
pelvis), or a fixed `tarpos_K`. Success (the paper: "the pelvis at or above the target
elevation"): the distance
sqrt(dxy^2 + max(0, target_z - pelvis_z)^2) stays within `success_threshold` until the
transition fires; being higher does not count against it.

Reward (TokenHSI's climb terms): `approach` walks the pelvis there, `elevation` pays the
pelvis near the target, and `feet_height` pays the feet at the top surface's height while the
pelvis is within reach of the object. Without the last, rising pays almost nothing until the
pelvis is already over the top (at the edge of a 0.5 m platform, rising the whole way moves
exp(-5 d^2) from 0.01 to 0.04), and a policy learns to come near and stay.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from detach.character.body import BODY_NAMES, FEET, FLOOR_TO_SOLE, FOOT_TO_SOLE, NUM_DOF, START_HEIGHT
from detach.skills.base import MidTaskStart, RewardTerm, Skill, Subtask
from detach.skills.context import OracleCommand, SkillContext
from detach.skills.kernels import approach, uniform_draw
from detach.skills.registry import register_skill
from detach.torch_math import box_corners_fast, index_on, quat_from_yaw, quat_rotate, wrap_angle


def climb_distance(root_pos: torch.Tensor, target: torch.Tensor) -> torch.Tensor:
    """sqrt(dxy^2 + max(0, target_z - pelvis_z)^2) [N], metres."""
    dxy = (root_pos[:, :2] - target[:, :2]).norm(dim=-1)
    below = (target[:, 2] - root_pos[:, 2]).clamp(min=0.0)
    return torch.sqrt(dxy * dxy + below * below)


def climb_approach(ctx: SkillContext) -> torch.Tensor:
    return approach(ctx, ctx.target)


def elevation(ctx: SkillContext) -> torch.Tensor:
    return torch.exp(-5.0 * ctx.dist ** 2)


FEET_KERNEL = 5.0
"""feet_height = exp(-FEET_KERNEL * err^2), err (m) the soles' mean height minus the top's:
0.29 at 0.5 m below, 0.64 at 0.3 m. (TokenHSI's 50, for a walking humanoid, pays 0.01 at
0.3 m below, and a puppet that raises its pelvis by an action would find no slope.)"""
REACH = 0.5
"""feet_height pays while the pelvis is within the object's XY half diagonal plus this (m). Beside
a small top (LH1's 0.6 m box) the feet reach its height without standing on it, and a puppet
learns that first: it climbs such a box only after about twice the iterations a wide platform
takes (results/laptop/NOTEBOOK.md, probe C7)."""
_FEET = tuple(BODY_NAMES.index(b) for b in FEET)


def feet_height(ctx: SkillContext) -> torch.Tensor:
    """The feet at the top surface's height, paid within reach of the object (0 farther)."""
    soles = ctx.state.body_pos[:, index_on(_FEET, ctx.state.body_pos.device), 2].mean(dim=-1) - FOOT_TO_SOLE
    top = ctx.target[:, 2] - ctx.cfg.env.climb_pelvis_height
    r = torch.exp(-FEET_KERNEL * (soles - top) ** 2)
    dxy = (ctx.state.root_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1)
    half = torch.where(ctx.has_obj, ctx.obj_half[:, :2].norm(dim=-1), torch.zeros_like(dxy))
    return torch.where(dxy <= half + REACH, r, torch.zeros_like(r))


def object_points(scene, attr: str, device: torch.device) -> torch.Tensor:
    """[n_obj, 3] an object-frame point of every scene object (e.g. `tar_climb_local`)."""
    pts = [list(getattr(o, attr)) for o in scene.objects]
    return torch.tensor(pts, dtype=torch.float32, device=device).reshape(-1, 3)


def object_point_world(ctx: SkillContext, local: torch.Tensor) -> torch.Tensor:
    """[N, 3] the object-frame points `local` [n_obj, 3] of each env's subtask object, in the
    world by the object's current pose (zeros when the scene has no object)."""
    if local.shape[0] == 0:
        return torch.zeros(ctx.num_envs, 3, device=local.device)
    return ctx.obj_pos + quat_rotate(ctx.obj_quat, local[ctx.obj.clamp(min=0)])


def object_top_point(ctx: SkillContext, local: torch.Tensor) -> torch.Tensor:
    """[N, 3] the climb points `local` [n_obj, 3] (on the top surface, object frame) of each
    env's subtask object, on the top the object has now: XY carried by its pose, the height its
    rotated bounding box's top plus the point's offset from the bbox top. For an upright object
    this is `object_point_world`; a box knocked over would otherwise put its climb point on its
    side at mid-height, where a policy standing beside the box met Climb's success rule."""
    if local.shape[0] == 0:
        return torch.zeros(ctx.num_envs, 3, device=local.device)
    point = local[ctx.obj.clamp(min=0)]
    flat = torch.cat((point[:, :2], torch.zeros_like(point[:, 2:])), dim=-1)
    xy = ctx.obj_pos[:, :2] + quat_rotate(ctx.obj_quat, flat)[:, :2]
    bbox_top = box_corners_fast(ctx.obj_pos, ctx.obj_quat, ctx.obj_half)[..., 2].max(dim=-1).values
    return torch.cat((xy, (bbox_top + point[:, 2] - ctx.obj_half[:, 2])[:, None]), dim=-1)


NEAR_RANGE = (0.2, 1.0)
"""A mid-task start stands this far (m) beyond the object's XY half diagonal from its centre."""
NEAR_YAW_NOISE = math.pi / 2
"""...facing the object's centre give or take this (rad)."""


@register_skill
class Climb(Skill):
    name = "climb"
    display_name = "Climb"
    color = (31, 119, 180)
    motion_labels = ("step_up", "walk")
    sources = ("scene", "tarpos")
    needs_object = True
    mid_task_reads_target = False
    reward_terms = {"approach": RewardTerm(climb_approach, 0.2), "elevation": RewardTerm(elevation, 0.5),
                    "feet_height": RewardTerm(feet_height, 0.3)}

    def bind(self, plan, services) -> None:
        super().bind(plan, services)
        self.local = object_points(services.scene, "tar_climb_local", self.device)

    def display_target(self, sub: Subtask, scene) -> np.ndarray | None:
        if sub.fixed_target is None and sub.obj >= 0:
            return scene.objects[sub.obj].to_world(scene.objects[sub.obj].tar_climb_local)
        return super().display_target(sub, scene)

    def target(self, ctx: SkillContext) -> torch.Tensor:
        climb = object_top_point(ctx, self.local)
        climb[:, 2] += self.services.cfg.env.climb_pelvis_height
        return torch.where(ctx.has_fixed[:, None], ctx.fixed_target, climb)

    def distance(self, ctx: SkillContext) -> torch.Tensor:
        return climb_distance(ctx.state.root_pos, ctx.target)

    def mid_task_start(self, objects, obj_rest, obj_half, target, gen) -> MidTaskStart:
        """Standing near the object, on any side, facing it within `NEAR_YAW_NOISE`: where
        LH1's Climb begins, beside the box Carry has just put down. The single-skill task's
        default start (2.5 m off, facing it) never shows a policy that state, and one that
        climbed from there walked into the box from LH1's starts and pushed it away
        (results/laptop/NOTEBOOK.md, C8). The object rests where it rests, axis-aligned."""
        n, dev = len(obj_rest), obj_rest.device

        def uniform(lo: float, hi: float) -> torch.Tensor:
            return uniform_draw(n, lo, hi, gen, dev)

        side, gap, turn = uniform(-math.pi, math.pi), uniform(*NEAR_RANGE), uniform(-NEAR_YAW_NOISE, NEAR_YAW_NOISE)
        reach = obj_half[:, :2].norm(dim=-1) + gap
        root_xy = obj_rest[:, :2] + torch.stack((side.cos(), side.sin()), -1) * reach[:, None]
        return MidTaskStart(root_xy, wrap_angle(side + math.pi + turn), torch.full((n,), START_HEIGHT, device=dev),
                            torch.zeros(n, NUM_DOF, device=dev), obj_rest.clone(),
                            quat_from_yaw(torch.zeros(n, device=dev)),
                            held=torch.zeros(n, dtype=torch.bool, device=dev))

    def oracle(self, ctx: SkillContext, cmd: OracleCommand, active: torch.Tensor) -> None:
        """Rise until the feet clear the top, move over the climb point, stand on it."""
        p, target = ctx.state.root_pos, ctx.target
        pxy = p[:, :2]
        surf = target[:, 2] - self.services.cfg.env.climb_pelvis_height
        lift = surf + START_HEIGHT + 0.1
        dxy = (target[:, :2] - pxy).norm(dim=-1)
        up = p[:, 2] > lift - 0.05
        vc = (2.5 * (target[:, :2] - pxy)).clamp(-1.2, 1.2)
        vc = torch.where((up | (dxy < 0.05))[:, None], vc, torch.zeros_like(vc))
        cmd.velocity = torch.where(active[:, None], vc, cmd.velocity)
        zc = torch.where(dxy < 0.05, surf + FLOOR_TO_SOLE + 0.01, lift)
        cmd.height = torch.where(active, torch.maximum(zc, cmd.height), cmd.height)
