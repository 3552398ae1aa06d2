"""Reference trajectories of `follow` subtasks, as time-stamped 2-D polylines.

A trajectory is a [V, 2] array of world XY vertices visited at a constant time step `dt`
(seconds); the reference point at time t (seconds since the subtask started) is the linear
interpolation between vertices, clamped to the last one. Two sources:

- procedural (`traj_rand`): random walks with the paper's parameters (speed 1.4-1.5 m/s,
  acceleration <= 2 m/s^2, sharp turns of 1.57 rad with probability 0.02 per vertex);
- fixed polylines from the task YAML, timed at a constant `speed` (m/s) along their length.

Batches of trajectories of different lengths are padded by repeating their last vertex, which
changes neither the interpolated reference (clamped there anyway) nor path distances.
"""

from __future__ import annotations

import math

import numpy as np
import torch

from detach.config.schema import TrajectoryGenCfg

FIXED_TRAJ_DT = 0.1
"""Vertex spacing in time (s) of YAML trajectories after timing them at the mean speed."""


def random_trajectories(start_xy: torch.Tensor, heading: torch.Tensor, cfg: TrajectoryGenCfg,
                        duration: float, generator: torch.Generator | None = None
                        ) -> tuple[torch.Tensor, float]:
    """Procedural trajectories starting at start_xy [n, 2] heading `heading` [n] (rad).

    Returns (vertices [n, cfg.num_verts, 2], dt) with dt = duration / (num_verts - 1) s.
    Speed does a bounded random walk within [speed_min, speed_max] whose change per vertex
    respects accel_max; the direction turns smoothly with a random rate bounded by the
    lateral acceleration accel_max / speed, plus rare sharp turns of +-sharp_turn_angle.
    """
    n, dev = start_xy.shape[0], start_xy.device
    V = int(cfg.num_verts)
    dt = float(duration) / (V - 1)

    def rand(*shape: int) -> torch.Tensor:
        return torch.rand(*shape, generator=generator, device=generator.device if generator else "cpu").to(dev)

    speed = torch.empty(n, V - 1, device=dev)
    v = cfg.speed_min + (cfg.speed_max - cfg.speed_min) * rand(n)
    dv = (2.0 * rand(n, V - 1) - 1.0) * cfg.accel_max * dt
    for k in range(V - 1):  # bounded random walk; V is ~100
        v = (v + dv[:, k]).clamp(cfg.speed_min, cfg.speed_max)
        speed[:, k] = v
    turn_rate = (2.0 * rand(n, V - 1) - 1.0) * cfg.accel_max / speed
    dtheta = turn_rate * dt
    sharp = rand(n, V - 1) < cfg.sharp_turn_prob
    sign = torch.where(rand(n, V - 1) < 0.5, -1.0, 1.0)
    dtheta = torch.where(sharp, sign * cfg.sharp_turn_angle, dtheta)
    dtheta[:, 0] = 0.0  # start along the given heading
    theta = heading[:, None] + torch.cumsum(dtheta, dim=1)
    step = torch.stack((torch.cos(theta), torch.sin(theta)), dim=-1) * (speed * dt)[..., None]
    verts = torch.cat((start_xy[:, None, :], start_xy[:, None, :] + torch.cumsum(step, dim=1)), dim=1)
    return verts, dt


def time_polyline(points: np.ndarray | list, speed: float, dt: float) -> np.ndarray:
    """Vertices [V, 2] of a polyline (waypoints [P, 2]) walked at `speed` m/s, one per dt s.

    The original waypoints are kept as vertices' targets only approximately (uniform
    resampling along the arc length); the final vertex is exactly the last waypoint.
    """
    pts = np.asarray(points, dtype=np.float64).reshape(-1, 2)
    if len(pts) == 1:
        return pts.copy()
    seg = np.linalg.norm(np.diff(pts, axis=0), axis=1)
    s = np.concatenate(([0.0], np.cumsum(seg)))
    total = s[-1]
    nv = max(int(math.ceil(total / (speed * dt))) + 1, 2)
    q = np.minimum(np.arange(nv) * speed * dt, total)
    q[-1] = total
    x = np.interp(q, s, pts[:, 0])
    y = np.interp(q, s, pts[:, 1])
    return np.stack((x, y), axis=1)


def pad_to(verts: torch.Tensor, length: int) -> torch.Tensor:
    """Pad [..., V, 2] to [..., length, 2] by repeating the last vertex."""
    V = verts.shape[-2]
    if V >= length:
        return verts[..., :length, :]
    last = verts[..., -1:, :].expand(*verts.shape[:-2], length - V, 2)
    return torch.cat((verts, last), dim=-2)


def sample_at(verts: torch.Tensor, dt: torch.Tensor, t: torch.Tensor) -> torch.Tensor:
    """Reference points at times t [n] or [n, k] (s) on trajectories verts [n, V, 2], dt [n].

    Linear interpolation between vertices; times beyond the end give the last vertex.
    Returns [n, 2] or [n, k, 2].
    """
    squeeze = t.dim() == 1
    if squeeze:
        t = t[:, None]
    V = verts.shape[1]
    u = (t / dt[:, None]).clamp(0.0, V - 1.0)
    i0 = u.floor().long().clamp(max=V - 2) if V > 1 else torch.zeros_like(u, dtype=torch.long)
    frac = (u - i0.to(u.dtype))[..., None]
    idx0 = i0[..., None].expand(-1, -1, 2)
    p0 = torch.gather(verts, 1, idx0)
    p1 = torch.gather(verts, 1, (idx0 + 1).clamp(max=V - 1))
    out = p0 + frac * (p1 - p0)
    return out[:, 0] if squeeze else out


def distance_to_polyline(p: torch.Tensor, verts: torch.Tensor) -> torch.Tensor:
    """XY distance (m) from points p [n, 2] to polylines verts [n, V, 2] (segments between
    consecutive vertices; a 1-vertex polyline is a point)."""
    if verts.shape[1] == 1:
        return (p - verts[:, 0]).norm(dim=-1)
    a, b = verts[:, :-1], verts[:, 1:]
    ab = b - a
    ap = p[:, None, :] - a
    denom = (ab * ab).sum(-1).clamp(min=1e-12)
    s = ((ap * ab).sum(-1) / denom).clamp(0.0, 1.0)
    closest = a + s[..., None] * ab
    return (p[:, None, :] - closest).norm(dim=-1).min(dim=1).values


class TrajectoryReference:
    """Each env's reference polyline [N, L, 2] (world XY), its vertex time step [N] (s) and
    the control step its subtask started at [N]: the reference point is `sample_at` the time
    since then. Follow subtasks load paths into it; other subtasks park it on the pelvis.

    YAML trajectories are timed at the generator's mean speed with `FIXED_TRAJ_DT` between
    vertices; procedural ones last `rand_duration` s, short enough to be reached and held
    (60 steps) before the episode's time limit, so that follow subtasks complete like fixed ones.
    """

    def __init__(self, trajectories: dict, cfg: TrajectoryGenCfg, num_envs: int, episode_length: int,
                 max_transition_steps: int, dt: float, device: torch.device) -> None:
        speed = 0.5 * (cfg.speed_min + cfg.speed_max)
        ids = sorted(trajectories)
        fixed = [torch.as_tensor(time_polyline(trajectories[k], speed, FIXED_TRAJ_DT), dtype=torch.float32,
                                 device=device) for k in ids]
        self.length = max([cfg.num_verts] + [f.shape[0] for f in fixed])
        self.fixed = {k: pad_to(f, self.length) for k, f in zip(ids, fixed)}
        margin = max(60, max_transition_steps) + 30
        self.rand_duration = max(episode_length - margin, episode_length // 2) * dt
        self.cfg, self.dt_control = cfg, dt
        self.verts = torch.zeros(num_envs, self.length, 2, device=device)
        self.vertex_dt = torch.full((num_envs,), FIXED_TRAJ_DT, device=device)
        self.t0 = torch.zeros(num_envs, dtype=torch.long, device=device)

    def restart(self, mask: torch.Tensor, steps: torch.Tensor) -> None:
        """The envs in mask [N] start a subtask now (steps [N]: every env's control step)."""
        self.t0 = torch.where(mask, steps, self.t0)

    def load_random(self, mask: torch.Tensor, start_xy: torch.Tensor, generator: torch.Generator) -> None:
        """New procedural paths from start_xy [N, 2] for the envs in mask [N] (drawn for every
        env, so that the number drawn needs no host read)."""
        heading = (torch.rand(len(mask), generator=generator, device=generator.device) * 2 - 1
                   ).to(self.verts.device) * math.pi
        verts, dt = random_trajectories(start_xy, heading, self.cfg, self.rand_duration, generator)
        self.verts = torch.where(mask[:, None, None], pad_to(verts, self.length), self.verts)
        self.vertex_dt.masked_fill_(mask, dt)

    def load_fixed(self, mask: torch.Tensor, key: int) -> None:
        """Trajectory `key` of the task for the envs in mask [N]."""
        self.verts = torch.where(mask[:, None, None], self.fixed[key], self.verts)
        self.vertex_dt.masked_fill_(mask, FIXED_TRAJ_DT)

    def park(self, mask: torch.Tensor, xy: torch.Tensor) -> None:
        """A constant reference at xy [N, 2] for the envs in mask [N] (subtasks that follow no
        path)."""
        self.verts = torch.where(mask[:, None, None], xy[:, None, :], self.verts)

    def reference(self, steps: torch.Tensor, ahead: float | torch.Tensor) -> torch.Tensor:
        """Reference XY [N, 2] `ahead` s from now (or [N, k, 2] for a tensor of times)."""
        t = (steps - self.t0).float() * self.dt_control
        if isinstance(ahead, torch.Tensor):
            return sample_at(self.verts, self.vertex_dt, t[:, None] + ahead[None])
        return sample_at(self.verts, self.vertex_dt, t + ahead)

    @property
    def end(self) -> torch.Tensor:
        """[N, 2] the last vertex of each env's path."""
        return self.verts[:, -1]
