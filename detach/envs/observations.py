"""Observations (docs/ARCHITECTURE.md, "Observations"): pure functions on batched tensors, and
`ObservationBuilder`, which assembles them into the TensorDict of every step.

Frames: everything is expressed in the character's heading frame (world rotated about +Z by
the root's yaw; +X = where the character faces) and, for positions, relative to the root
(pelvis) unless stated otherwise. Quaternions are wxyz. Units: metres, radians, m/s, rad/s.

Groups and their frame layouts (sizes for the 15-body, 32-DoF character):

- `self` (287 per frame): root height (1), positions of the 14 non-root bodies (42), rotations
  of the 15 bodies as tangent/normal 6-D (90), linear (45) and angular (45) velocities of the
  15 bodies, hinge positions (32) and velocities (32). Proprioception only.
- `env` (681 per frame): the place to make for now (`Skill.goal`: the subtask's target, but
  Carry's box until it is carried) relative to the root (3); `env.trajectory.num_samples`
  (10) path points `sample_dt` (0.5 s) apart, XY relative to the root (20; the target's XY
  repeated outside subtasks that follow a path); the subtask's object: position relative to
  the root (3), rotation 6-D (6), its 8 bounding-box corners relative to the root (24), zeros
  when the subtask has no object;
  the 25 x 25 local height map (625): world-Z surface heights on a grid of 0.1 m spacing
  centred on the root and aligned with the heading (row-major, x forward then y left).
  Environment only: nothing here depends on the character's joints or velocities.
- `task` (4): one-hot of the current skill in skill-registry order (`detach.skills`).
- `amp` (89 per frame, 10 frames): root height (1), root rotation 6-D in the heading frame
  (6), root linear and angular velocity in the heading frame (3 + 3), hinge positions (32)
  and velocities (32), hand and foot positions relative to the root, heading frame (12).
  `amp_frame` is the single definition: motion clips must be featurised with it too.
- `critic` (977): the newest `self` and `env` frames, `task`, and privileged extras: the
  subtask object's linear velocity (heading frame, 3), the transition hold progress (1),
  and the plan progress (1).
"""

from __future__ import annotations

import math

import torch
from tensordict import TensorDict

from detach.config.schema import EnvCfg
from detach.envs.obs_spec import ObsSpec
from detach.host_sync import may_any, reads_are_free
from detach.sim.raster import Raster
from detach.torch_math import box_corners_fast, heading_matrix, quat_axes_xz, quat_to_matrix, yaw_of

NUM_BODIES = 15
NUM_DOF = 32
NUM_KEY_BODIES = 4
SELF_DIM = 1 + 3 * (NUM_BODIES - 1) + 6 * NUM_BODIES + 3 * NUM_BODIES + 3 * NUM_BODIES + 2 * NUM_DOF
AMP_DIM = 1 + 6 + 3 + 3 + 2 * NUM_DOF + 3 * NUM_KEY_BODIES
CRITIC_EXTRA = 5


def env_dim(grid: int, path_samples: int = 10) -> int:
    """Width of one env frame for a grid x grid height map and `path_samples` path points."""
    return 3 + 2 * path_samples + 3 + 6 + 24 + grid * grid


def _heading(root_quat: torch.Tensor, R: torch.Tensor | None) -> torch.Tensor:
    return heading_matrix(yaw_of(root_quat)) if R is None else R


def _to_heading(v: torch.Tensor, R: torch.Tensor) -> torch.Tensor:
    """World vectors v [N, M, 3] in the heading frame of R [N, 3, 3] (a rotation about +Z):
    `v @ R`, written elementwise. Why: a batched product of [M, 3] by [3, 3] matrices is one
    slow library call per use on a CPU (~50 us at N = 64) that `torch.compile` cannot fuse."""
    c, s = R[:, None, 0, 0], R[:, None, 1, 0]
    x, y = v[..., 0], v[..., 1]
    return torch.stack((c * x + s * y, c * y - s * x, v[..., 2]), dim=-1)


def self_frame(body_pos: torch.Tensor, body_quat: torch.Tensor, body_lin: torch.Tensor,
               body_ang: torch.Tensor, dof_pos: torch.Tensor, dof_vel: torch.Tensor,
               R: torch.Tensor | None = None) -> torch.Tensor:
    """One proprioception frame [N, 287]; body_* are [N, 15, .] world-frame with the root
    first; R [N, 3, 3] the heading matrix of the root (computed when None)."""
    n = body_pos.shape[0]
    R = _heading(body_quat[:, 0], R)
    rel = _to_heading(body_pos[:, 1:] - body_pos[:, :1], R)
    axes = _to_heading(quat_axes_xz(body_quat).reshape(n, -1, 3), R)
    vel = _to_heading(torch.cat((body_lin, body_ang), dim=1), R)
    return torch.cat((body_pos[:, 0, 2:3], rel.reshape(n, -1), axes.reshape(n, -1), vel.reshape(n, -1),
                      dof_pos, dof_vel), dim=-1)


def amp_frame(root_pos: torch.Tensor, root_quat: torch.Tensor, root_lin: torch.Tensor,
              root_ang: torch.Tensor, dof_pos: torch.Tensor, dof_vel: torch.Tensor,
              key_pos: torch.Tensor, R: torch.Tensor | None = None) -> torch.Tensor:
    """One AMP discriminator frame [N, 89] from world-frame inputs (key_pos [N, 4, 3])."""
    n = root_pos.shape[0]
    R = _heading(root_quat, R)
    vecs = _to_heading(torch.cat((quat_axes_xz(root_quat).reshape(n, 2, 3), root_lin[:, None], root_ang[:, None],
                                  key_pos - root_pos[:, None]), dim=1), R)
    return torch.cat((root_pos[:, 2:3], vecs[:, :4].reshape(n, -1), dof_pos, dof_vel,
                      vecs[:, 4:].reshape(n, -1)), dim=-1)


def amp_index(key_bodies: list[int]) -> torch.Tensor:
    """Where each entry of an AMP frame sits in a self frame (both from the same state), so the
    env builds `amp` with one gather: `self_frame(...)[:, amp_index(k)] == amp_frame(...)`.
    key_bodies: indices (>= 1) of the key bodies among the 15."""
    o_rot = 1 + 3 * (NUM_BODIES - 1)
    o_lin = o_rot + 6 * NUM_BODIES
    o_ang = o_lin + 3 * NUM_BODIES
    o_dof = o_ang + 3 * NUM_BODIES
    idx = [0, *range(o_rot, o_rot + 6), *range(o_lin, o_lin + 3), *range(o_ang, o_ang + 3),
           *range(o_dof, o_dof + 2 * NUM_DOF)]
    idx += [1 + 3 * (k - 1) + j for k in key_bodies for j in range(3)]
    return torch.tensor(idx, dtype=torch.long)


def height_grid_offsets(grid: int, spacing: float, device: torch.device | str) -> torch.Tensor:
    """[grid*grid, 3] heading-frame offsets (m, z = 0) of the local height-map points,
    centred on the root, row-major with x (forward) the slow index."""
    r = (torch.arange(grid, device=device, dtype=torch.float32) - (grid - 1) / 2.0) * spacing
    gx, gy = torch.meshgrid(r, r, indexing="ij")
    return torch.stack((gx.reshape(-1), gy.reshape(-1), torch.zeros(grid * grid, device=device)), dim=-1)


def local_height_map(root_pos: torch.Tensor, R: torch.Tensor, offsets: torch.Tensor, raster: Raster,
                     dyn_pos: torch.Tensor, dyn_quat: torch.Tensor, dyn_half: torch.Tensor) -> torch.Tensor:
    """[N, P] world-Z surface heights at the grid points around the root (heading-aligned):
    the static raster, raised to the top of any moving box whose footprint covers a point.

    offsets [P, 3] heading-frame grid offsets; dyn_pos [N, K, 3], dyn_quat [N, K, 4] (wxyz),
    dyn_half [K, 3]. On a CPU only the (env, box) pairs within reach of the grid are
    evaluated, so far-away boxes cost nothing; on an accelerator every pair is, masked.
    """
    c, s = R[:, 0, 0], R[:, 1, 0]
    # world XY of every point, expressed directly in the raster's sampling coordinates (u from
    # world y, v from world x), elementwise: no batched matrix product (see `_to_heading`)
    base = root_pos[:, :2].flip(-1) * raster.scale - raster.shift  # [N, 2] (u, v) of the root
    ox, oy, cn, sn = offsets[:, 0], offsets[:, 1], c[:, None], s[:, None]
    uv = torch.stack((base[:, 0, None] + raster.su * (sn * ox + cn * oy),
                      base[:, 1, None] + raster.sv * (cn * ox - sn * oy)), dim=-1)  # [N, P, 2]
    h = raster.sample_uv(uv)
    K = dyn_pos.shape[1]
    if K == 0:
        return h
    if not reads_are_free(dyn_pos):  # every pair at once: their number would need a host read
        return torch.maximum(h, _box_tops_on_grid(root_pos, c, s, offsets, dyn_pos, dyn_quat, dyn_half[None]))
    reach = math.sqrt(2.0) * offsets[:, :2].abs().amax() + dyn_half[:, :2].norm(dim=-1)  # [K]
    near = (dyn_pos[..., :2] - root_pos[:, None, :2]).norm(dim=-1) < reach
    e, k = near.nonzero(as_tuple=True)  # gather the pairs within reach
    if len(e) == 0:
        return h
    tops = _box_tops_on_grid(root_pos[e], c[e], s[e], offsets, dyn_pos[e, k, None],
                             dyn_quat[e, k, None], dyn_half[k, None])  # [M, P]
    return h.scatter_reduce(0, e[:, None].expand_as(tops), tops, reduce="amax")


def _box_tops_on_grid(root_pos: torch.Tensor, c: torch.Tensor, s: torch.Tensor, offsets: torch.Tensor,
                      box_pos: torch.Tensor, box_quat: torch.Tensor, half: torch.Tensor) -> torch.Tensor:
    """[N, P] the highest top (world Z) of the boxes whose footprints cover grid point p of env
    n, else 0. root_pos [N, 3], c, s [N] cos and sin of the heading, offsets [P, 3], box_pos
    [N, K, 3], box_quat [N, K, 4], half [N or 1, K, 3].

    A grid point's coordinates in box k's frame are affine in its offsets (ox, oy): lx = a0 +
    ox a1 + oy a2, ly = b0 + ox b1 + oy b2, with coefficients per (env, box). So the work per
    point is a few multiply-adds, one box at a time (K is small): elementwise [N, P] loops that
    a compiled step fuses into one, and no batched matrix product."""
    Rb = quat_to_matrix(box_quat)  # [N, K, 3, 3]; box frame coordinates = (world offset) @ Rb
    ex, ey = root_pos[:, None, 0] - box_pos[..., 0], root_pos[:, None, 1] - box_pos[..., 1]  # [N, K]
    c, s = c[:, None], s[:, None]
    coef = []  # (x, y) of the box frame: (constant, per ox, per oy), each [N, K]
    for j in (0, 1):
        r0, r1 = Rb[..., 0, j], Rb[..., 1, j]
        coef.append((ex * r0 + ey * r1, c * r0 + s * r1, c * r1 - s * r0))
    n, k = box_pos.shape[:2]
    top = box_corners_fast(box_pos.reshape(-1, 3), box_quat.reshape(-1, 4), half.expand(n, k, 3).reshape(-1, 3))
    top = top[..., 2].amax(dim=-1).reshape(n, k)
    hx, hy = half[..., 0].expand(n, k), half[..., 1].expand(n, k)
    ox, oy = offsets[:, 0], offsets[:, 1]
    out = torch.zeros(n, offsets.shape[0], dtype=root_pos.dtype, device=root_pos.device)
    for b in range(k):
        (x0, x1, x2), (y0, y1, y2) = ((t[:, b, None] for t in axis) for axis in coef)
        inside = ((x0 + ox * x1 + oy * x2).abs() <= hx[:, b, None]) & ((y0 + ox * y1 + oy * y2).abs() <= hy[:, b, None])
        out = torch.maximum(out, torch.where(inside, top[:, b, None], torch.zeros_like(out)))
    return out


def env_frame(root_pos: torch.Tensor, R: torch.Tensor, target: torch.Tensor,
              traj_samples: torch.Tensor, is_traj: torch.Tensor, has_obj: torch.Tensor,
              obj_pos: torch.Tensor, obj_quat: torch.Tensor, obj_half: torch.Tensor,
              height_map: torch.Tensor) -> torch.Tensor:
    """One environment frame [N, 681 for a 25x25 map] (see module doc).

    target [N, 3] world; traj_samples [N, 10, 2] world XY; is_traj, has_obj [N] bool;
    obj_pos [N, 3], obj_quat [N, 4], obj_half [N, 3] of the subtask's object; R [N, 3, 3]
    the root's heading matrix.
    """
    n, T = root_pos.shape[0], traj_samples.shape[1]
    smp = torch.where(is_traj[:, None, None], traj_samples, target[:, None, :2])
    smp = torch.cat((smp, root_pos[:, None, 2:].expand(n, T, 1)), dim=-1)
    corners = box_corners_fast(obj_pos, obj_quat, obj_half)
    pts = _to_heading(torch.cat((target[:, None], smp, obj_pos[:, None], corners), dim=1) - root_pos[:, None], R)
    axes = _to_heading(quat_axes_xz(obj_quat).reshape(n, 2, 3), R).reshape(n, 6)
    obj = torch.cat((pts[:, T + 1], axes, pts[:, T + 2:].reshape(n, -1)), dim=-1) * has_obj[:, None]
    return torch.cat((pts[:, 0], pts[:, 1:T + 1, :2].reshape(n, -1), obj, height_map), dim=-1)


class History:
    """A [N, T, d] frame buffer, oldest first; `push` appends the newest frame."""

    def __init__(self, n: int, steps: int, dim: int, device: torch.device | str) -> None:
        self.buf = torch.zeros(n, steps, dim, device=device)

    def push(self, frame: torch.Tensor) -> None:
        self.buf = torch.cat((self.buf[:, 1:], frame[:, None]), dim=1)

    def fill(self, mask: torch.Tensor, frame: torch.Tensor) -> None:
        """Set every step of the envs in mask [N] to their row of frame [N, d] (after a reset:
        no past yet). A mask, not indices: the same shapes at every step (`sim.compile`)."""
        self.buf = torch.where(mask[:, None, None], frame[:, None], self.buf)

    def flat(self) -> torch.Tensor:
        return self.buf.reshape(self.buf.shape[0], -1)

    @property
    def newest(self) -> torch.Tensor:
        return self.buf[:, -1]


class ObservationBuilder:
    """Assembles the observation TensorDict of every step from the state and the skills'
    targets, keeping the `self`, `env` and `amp` histories (see the module docstring)."""

    def __init__(self, cfg: EnvCfg, num_envs: int, skills: tuple[str, ...], num_actions: int, raster: Raster,
                 key_bodies: list[int], dyn: torch.Tensor, obj_half: torch.Tensor, device: torch.device) -> None:
        hm, samples = cfg.height_map, cfg.trajectory.num_samples
        num_skills = len(skills)
        self.cfg, self.num_envs, self.num_skills, self.device = cfg, num_envs, num_skills, device
        self.skill_ids = torch.arange(num_skills, device=device)
        self.raster, self.dyn, self.obj_half = raster, dyn, obj_half
        self.hm_offsets = height_grid_offsets(hm.grid, hm.spacing, device)
        self.amp_idx = amp_index(key_bodies).to(device)
        self.spec = ObsSpec(
            self_steps=cfg.history_self, self_dim=SELF_DIM, env_steps=cfg.history_env,
            env_dim=env_dim(hm.grid, samples), height_map_cells=hm.grid * hm.grid, num_skills=num_skills,
            critic_dim=SELF_DIM + env_dim(hm.grid, samples) + num_skills + CRITIC_EXTRA,
            amp_steps=cfg.amp_obs_steps, amp_dim=AMP_DIM, num_actions=num_actions, skills=skills)
        self.h_self = History(num_envs, cfg.history_self, SELF_DIM, device)
        self.h_env = History(num_envs, cfg.history_env, env_dim(hm.grid, samples), device)
        self.h_amp = History(num_envs, cfg.amp_obs_steps, AMP_DIM, device)
        self.sample_times = torch.arange(samples, device=device) * cfg.trajectory.sample_dt

    def build(self, ctx, reset: torch.Tensor, path_ahead: torch.Tensor, follows_path: torch.Tensor,
              hold: torch.Tensor, progress: torch.Tensor) -> TensorDict:
        """Observations of the state in ctx (a `SkillContext` with targets); the envs in reset
        [N] (bool) get their whole history filled with this frame. path_ahead [N, num_samples, 2] are the
        reference points `sample_times` ahead; follows_path [N] says where they are shown;
        hold and progress [N] are the transition hold fraction and the plan fraction done."""
        st = ctx.state
        R = heading_matrix(yaw_of(st.root_quat))
        dyn = self.dyn
        if self.cfg.height_map.enabled:
            hmap = local_height_map(st.root_pos, R, self.hm_offsets, self.raster, st.obj_pos[:, dyn],
                                    st.obj_quat[:, dyn], self.obj_half[dyn])
        else:
            hmap = torch.zeros(self.num_envs, self.hm_offsets.shape[0], device=self.device)
        f_self = self_frame(st.body_pos, st.body_quat, st.body_lin, st.body_ang, st.dof_pos, st.dof_vel, R)
        f_env = env_frame(st.root_pos, R, ctx.goal, path_ahead, follows_path, ctx.has_obj, ctx.obj_pos,
                          ctx.obj_quat, ctx.obj_half, hmap)
        f_amp = f_self[:, self.amp_idx]  # == amp_frame(...) of the same state (tested)
        restart = may_any(reset)
        for h, f in ((self.h_self, f_self), (self.h_env, f_env), (self.h_amp, f_amp)):
            h.push(f)
            if restart:
                h.fill(reset, f)
        task = (ctx.skill[:, None] == self.skill_ids).float()  # F.one_hot checks its input on the host
        extra = torch.cat((_to_heading(ctx.obj_lin[:, None], R)[:, 0] * ctx.has_obj[:, None], hold[:, None],
                           progress[:, None]), dim=-1)
        critic = torch.cat((f_self, f_env, task, extra), dim=-1)
        return TensorDict({"self": self.h_self.flat(), "env": self.h_env.flat(), "task": task,
                           "critic": critic, "amp": self.h_amp.flat()}, batch_size=[self.num_envs],
                          device=self.device)
