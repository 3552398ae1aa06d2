"""A scripted, privileged controller of the puppet that executes any plan, and an evaluator.

The oracle proves the task logic (targets, transitions, success tests) end to end: with it the
LH tasks must succeed almost always, while a random policy must almost never succeed. It
reads the env's true state (poses, the current subtask, trajectories, the scene raster) and
drives the puppet's root servos, pose and grasp (`detach.envs.puppet`), batched over envs:

- traj: track the moving reference point (feed-forward velocity + proportional correction);
- carry: walk to the box face opposite its destination (via a point in front of that face),
  bend over until both hands rest on the lid, grasp, lift 0.2 m, translate (without turning)
  until the box is 0.1 m short of the destination, lower it, and hold until the transition;
- climb: rise until the feet clear the top, move over the climb point, stand on it;
- sit: take a long-sitting pose (hips flexed 90 deg, legs straight) facing the first of the
  object's facing direction and its 90/180 deg turns whose leg line is free, rise above
  everything around the seat, move over the sit point and lower onto the seat.
"""

from __future__ import annotations

import math
from typing import Callable

import torch

from detach.envs import humanoid as H
from detach.envs import puppet as P
from detach.envs import success as S
from detach.envs.actions import pd_actions
from detach.envs.torch_math import quat_rotate, wrap_angle, yaw_of

_DOF = {n: i for i, n in enumerate(H.DOF_NAMES)}


def _pose(**angles: float) -> torch.Tensor:
    q = torch.zeros(H.NUM_DOF)
    for name, v in angles.items():
        q[_DOF[name]] = v
    return q


SIT_POSE = _pose(right_hip_y=-1.57, left_hip_y=-1.57, right_shoulder_y=-1.2, left_shoulder_y=-1.2)
"""Long sitting: thighs and shins straight forward, arms reaching forward above the seat."""
LIFT = 0.2
"""How far (m) the puppet raises a grasped box."""


def reach_pose(top_z: torch.Tensor, pelvis_z: float = H.START_HEIGHT) -> tuple[torch.Tensor, torch.Tensor]:
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
    q = torch.zeros(len(top_z), H.NUM_DOF)
    q[:, _DOF["abdomen_y"]] = phi
    q[:, _DOF["right_shoulder_y"]] = -beta - phi
    q[:, _DOF["left_shoulder_y"]] = -beta - phi
    return q, sx + arm * torch.sin(beta)


class PuppetOracle:
    """`oracle(env) -> actions [N, 37]`, callable once per control step."""

    def __init__(self, env) -> None:
        if not env.puppet:
            raise ValueError("the oracle drives the puppet character: set env.character=puppet")
        self.env = env
        self.dev = env.device
        sit_face = []
        for s in env.plan:
            if s.skill == "sit" and s.obj >= 0:
                sit_face.append(self._sit_heading(s.obj))
            else:
                sit_face.append(0.0)
        self.sit_heading = torch.tensor(sit_face, device=self.dev)
        self.dyn_slot = torch.full((max(len(env.scene.objects), 1),), -1, dtype=torch.long, device=self.dev)
        for k, i in enumerate(env.ix.dyn.tolist()):
            self.dyn_slot[i] = k

    # -------------------------------------------------------------------------- helpers
    def _ground(self, xy: torch.Tensor, radius: float = 0.2) -> torch.Tensor:
        """Highest static surface (m) within `radius` of points xy [n, 2]."""
        r = torch.tensor([[0, 0], [radius, 0], [-radius, 0], [0, radius], [0, -radius]], device=self.dev)
        return self.env.raster.sample(xy[:, None] + r).max(dim=-1).values

    def _sit_heading(self, obj: int) -> float:
        """Yaw (rad) to sit on object obj facing a direction whose leg line is free."""
        o = self.env.scene.objects[obj]
        seat = torch.as_tensor(o.tar_sit_world, dtype=torch.float32, device=self.dev)
        base = o.z_rot + math.pi / 2  # the object faces its local +Y
        best, best_h = base, float("inf")
        for k in (0, 1, 3, 2):
            yaw = base + k * math.pi / 2
            t = torch.linspace(0.25, 1.0, 16, device=self.dev)
            pts = seat[:2] + t[:, None] * torch.tensor([math.cos(yaw), math.sin(yaw)], device=self.dev)
            h = float(self.env.raster.sample(pts).max())
            if h <= seat[2] - 0.1 + 0.03:
                return yaw
            if h < best_h:
                best, best_h = yaw, h
        return best

    def _clearance(self, frm: torch.Tensor, to: torch.Tensor) -> torch.Tensor:
        """Highest static surface (m) along segments frm -> to [n, 2] and within 1 m of `to`."""
        t = torch.linspace(0.0, 1.0, 24, device=self.dev)
        line = frm[:, None] + t[None, :, None] * (to - frm)[:, None]
        ang = torch.linspace(0, 2 * math.pi, 13, device=self.dev)[:-1]
        ring = torch.cat([to[:, None] + r * torch.stack((ang.cos(), ang.sin()), -1)[None] for r in (0.4, 0.8, 1.05)], 1)
        return self.env.raster.sample(torch.cat((line, ring), 1)).max(dim=-1).values

    # -------------------------------------------------------------------------- control
    def __call__(self, env=None) -> torch.Tensor:
        env = self.env
        st = env._last_state
        n, dev = env.num_envs, self.dev
        tg = env._targets(st)
        p, yaw = st.root_pos, yaw_of(st.root_quat)
        pxy = p[:, :2]
        ground = self._ground(pxy)
        v = torch.zeros(n, 2, device=dev)
        yaw_d = yaw.clone()
        z_d = ground + H.START_HEIGHT
        q = torch.zeros(n, H.NUM_DOF, device=dev)
        grasp = torch.full((n,), -1.0, device=dev)
        skill, target = tg["skill"], tg["target"]

        # traj -------------------------------------------------------------------------
        m = skill == S.TRAJ
        if bool(m.any()):
            ref = env._traj_ref(0.0)
            ff = (env._traj_ref(env.dt) - ref) / env.dt
            vt = ff + 3.0 * (ref - pxy)
            v = torch.where(m[:, None], vt, v)
            moving = vt.norm(dim=-1) > 0.3
            yaw_d = torch.where(m & moving, torch.atan2(vt[:, 1], vt[:, 0]), yaw_d)

        # carry ------------------------------------------------------------------------
        m = skill == S.CARRY
        if bool(m.any()):
            box, bq = tg["obj_pos"], tg["obj_quat"]
            half = tg["obj_half"]
            slot = self.dyn_slot[tg["obj"].clamp(min=0)]
            held = (env.grasp_obj == slot) & (slot >= 0)
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
            q_reach, reach = reach_pose(top.cpu())
            q_reach, reach = q_reach.to(dev), reach.to(dev)
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
            delivered = ((box - target).norm(dim=-1) <= env.threshold) & ~held
            vm = torch.where(held[:, None], v_carry, torch.where(delivered[:, None], torch.zeros_like(v_app), v_app))
            v = torch.where(m[:, None], vm, v)
            yaw_d = torch.where(m & ~held & (d_stand < 1.5), face, yaw_d)
            yaw_d = torch.where(m & ~held & (d_stand >= 1.5), torch.atan2(v_app[:, 1], v_app[:, 0]), yaw_d)
            z_c = torch.where(held & ~at_dest, z_d + LIFT, z_d)
            z_d = torch.where(m, z_c, z_d)
            near = m & (d_stand < 0.4)
            q = torch.where((near | held)[:, None], q_reach, q)
            grasp = torch.where(m & ((arrived & ~delivered) | held), torch.ones_like(grasp), grasp)

        # climb ------------------------------------------------------------------------
        m = skill == S.CLIMB
        if bool(m.any()):
            surf = target[:, 2] - env.cfg.env.climb_pelvis_height
            lift = surf + H.START_HEIGHT + 0.1
            dxy = (target[:, :2] - pxy).norm(dim=-1)
            up = p[:, 2] > lift - 0.05
            vc = (2.5 * (target[:, :2] - pxy)).clamp(-1.2, 1.2)
            vc = torch.where((up | (dxy < 0.05))[:, None], vc, torch.zeros_like(vc))
            v = torch.where(m[:, None], vc, v)
            zc = torch.where(dxy < 0.05, surf + H.FLOOR_TO_SOLE + 0.01, lift)
            z_d = torch.where(m, torch.maximum(zc, z_d), z_d)

        # sit --------------------------------------------------------------------------
        m = skill == S.SIT
        if bool(m.any()):
            dxy = (target[:, :2] - pxy).norm(dim=-1)
            far = dxy > 2.0
            clear = self._clearance(pxy, target[:, :2]) + 0.2
            up = p[:, 2] > clear - 0.05
            vs = (2.5 * (target[:, :2] - pxy)).clamp(-1.2, 1.2)
            vs = torch.where((far | up | (dxy < 0.04))[:, None], vs, torch.zeros_like(vs))
            v = torch.where(m[:, None], vs, v)
            heading = self.sit_heading[env.subtask]
            yaw_d = torch.where(m & far, torch.atan2(vs[:, 1], vs[:, 0]), torch.where(m, heading, yaw_d))
            zs = torch.where(dxy < 0.04, target[:, 2] - 0.1, torch.maximum(clear, z_d))
            z_d = torch.where(m & ~far, zs, z_d)
            q = torch.where((m & ~far)[:, None], SIT_POSE.to(dev), q)

        return self._actions(v, yaw, yaw_d, z_d, q, grasp)

    def _actions(self, v, yaw, yaw_d, z_d, q, grasp) -> torch.Tensor:
        env = self.env
        a = torch.zeros(env.num_envs, P.NUM_ACTIONS, device=self.dev)
        a[:, :H.NUM_DOF] = pd_actions(q, env.dof_lo, env.dof_hi)
        c, s = torch.cos(yaw), torch.sin(yaw)
        a[:, 32] = (c * v[:, 0] + s * v[:, 1]) / P.ROOT_LIN_SPEED
        a[:, 33] = (-s * v[:, 0] + c * v[:, 1]) / P.ROOT_LIN_SPEED
        a[:, 34] = (5.0 * wrap_angle(yaw_d - yaw)).clamp(-P.ROOT_YAW_RATE, P.ROOT_YAW_RATE) / P.ROOT_YAW_RATE
        a[:, 35] = P.height_to_action(z_d)
        a[:, 36] = grasp
        return a.clamp(-1.0, 1.0)


def random_policy(env, generator: torch.Generator | None = None) -> Callable[[object], torch.Tensor]:
    """Uniform random actions in [-1, 1]."""
    gen = generator or torch.Generator().manual_seed(0)
    return lambda _env=None: (torch.rand(env.num_envs, env.num_actions, generator=gen) * 2 - 1).to(env.device)


def evaluate(env, policy: Callable[[object], torch.Tensor], trials: int,
             on_step: Callable[[dict], None] | None = None) -> dict:
    """Run `policy` until every env has finished ceil(trials / N) episodes (counting only
    those, so that quick failures are not over-represented); aggregate the paper's metrics.

    Returns per-subtask mean scores, the LH success rate, mean execution time (s) of
    successful episodes, and the raw per-episode rows.
    """
    n = env.num_envs
    per_env = max(1, math.ceil(trials / n))
    count = torch.zeros(n, dtype=torch.long)
    rows: list[dict] = []
    env._reset_envs(torch.arange(n, device=env.device))
    env.obs = env._observe(env._read(), torch.arange(n, device=env.device))
    while bool((count < per_env).any()):
        _, _, dones, extras = env.step(policy(env))
        if on_step is not None:
            on_step(extras)
        if "episode_progress" not in extras:
            continue
        prog = extras["episode_progress"]
        for i in dones.nonzero(as_tuple=False).squeeze(-1).tolist():
            if count[i] < per_env:
                rows.append({k: v[i].detach().cpu() for k, v in prog.items()})
            count[i] += 1
    scores = torch.stack([r["score"] for r in rows])
    lh = torch.stack([r["lh_success"] for r in rows]).float()
    ends = torch.stack([r["end"] for r in rows])
    t_ok = ends[lh.bool(), -1].float() * env.dt
    return {
        "trials": len(rows),
        "subtask_success": scores.mean(0).tolist(),
        "lh_success": float(lh.mean()),
        "exec_time": float(t_ok.mean()) if len(t_ok) else float("nan"),
        "fall_rate": float(torch.stack([r["fell"] for r in rows]).float().mean()),
        "rows": rows,
    }
