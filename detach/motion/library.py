"""MotionLib: every clip packed into contiguous tensors, queried in batches by (clip, time).

ProtoMotions-style: frames of all clips are concatenated along one axis (`root_pos` [T, 3],
`dof_pos` [T, 32], `body_pos` [T, 15, 3], ...) with per-clip `clip_start` offsets and
`clip_frames` counts, on one device. A query for N (clip id, time) pairs is a handful of
gathers and lerps, with no Python loop over samples:
positions, angles and velocities are interpolated linearly between the two neighbouring
frames, the root quaternion by slerp. Velocities are computed once at load by central finite
differences within each clip (one-sided at the first/last frame): root linear velocity, root
angular velocity (world frame, from q[k+1] * q[k-1]^-1), hinge velocities, body velocities.

Sampling: `skill_weights` maps skill labels to probabilities (normalised over the labels that
have clips; default: uniform over the labels present). Within a label, clips are equally
likely (`weight_by_length=False`, default, so a long idle clip does not crowd out short step-ups)
or proportional to their duration (`weight_by_length=True`, i.e. every second of motion of that
label equally likely). Times are uniform within a clip.
"""

from __future__ import annotations

import os
from collections.abc import Iterable, Sequence
from pathlib import Path

import numpy as np
import torch

from detach.character.body import BODY_NAMES, KEY_BODIES
from detach.torch_math import quat_conj, quat_mul
from detach.motion.clip import ClipError, MotionClip, load_clip, load_clips
from detach.motion.rotations import quat_continuous
from detach.motion.labels import MOTION_LABELS
from detach.motion.state import MotionState

ClipSource = MotionClip | str | os.PathLike


class MotionLib:
    """Packed reference motions on `device`; see the module docstring for the semantics."""

    def __init__(self, clips: ClipSource | Iterable[ClipSource], device: str | torch.device = "cpu",
                 skill_weights: dict[str, float] | None = None, weight_by_length: bool = False,
                 dtype: torch.dtype = torch.float32) -> None:
        """clips: MotionClip objects, clip files and/or folders of `*.npz` clips (or one of these)."""
        self.device = torch.device(device)
        self.dtype = dtype
        self.clips = _gather(clips)
        if not self.clips:
            raise ClipError(f"no motion clips given ({clips!r})")
        names = [c.name for c in self.clips]
        dup = sorted({n for n in names if names.count(n) > 1})
        if dup:
            raise ClipError(f"duplicate clip name(s): {', '.join(dup)}")
        self.clip_names: list[str] = names
        self._pack()
        self.key_body_ids = torch.tensor([BODY_NAMES.index(b) for b in KEY_BODIES], device=self.device)
        self.weight_by_length = weight_by_length
        self.set_skill_weights(skill_weights)

    # --- loading ------------------------------------------------------------------------

    def _pack(self) -> None:
        cs = self.clips
        frames = np.array([c.num_frames for c in cs])
        fps = np.array([c.fps for c in cs], dtype=np.float64)
        start = np.concatenate(([0], np.cumsum(frames)[:-1]))
        cat = lambda key: np.concatenate([getattr(c, key) for c in cs])  # noqa: E731
        root_pos, dof_pos, body_pos = cat("root_pos"), cat("dof_pos"), cat("body_pos")
        root_quat = np.concatenate([quat_continuous(c.root_quat) for c in cs])
        dev, dt = self.device, self.dtype
        t = lambda x: torch.as_tensor(x, dtype=torch.float64, device=dev)  # noqa: E731
        self.clip_start = torch.as_tensor(start, dtype=torch.long, device=dev)
        self.clip_frames = torch.as_tensor(frames, dtype=torch.long, device=dev)
        self.clip_fps = t(fps)
        self.clip_length = t((frames - 1) / fps).to(dt)
        """[C] clip durations, seconds."""
        self.clip_skill = torch.as_tensor([MOTION_LABELS.index(c.skill) for c in cs], dtype=torch.long, device=dev)
        """[C] index of each clip's label in MOTION_LABELS."""
        # central differences inside each clip (one-sided at its ends), in float64
        clip_of = torch.repeat_interleave(torch.arange(len(cs), device=dev), self.clip_frames)
        idx = torch.arange(int(frames.sum()), device=dev)
        first = self.clip_start[clip_of]
        last = first + self.clip_frames[clip_of] - 1
        prev, nxt = torch.maximum(idx - 1, first), torch.minimum(idx + 1, last)
        span = (nxt - prev).to(torch.float64) / self.clip_fps[clip_of]
        inv = torch.where(span > 0, 1.0 / span.clamp_min(1e-12), torch.zeros_like(span))

        def diff(x: torch.Tensor) -> torch.Tensor:
            return (x[nxt] - x[prev]) * inv.view(-1, *([1] * (x.dim() - 1)))

        rp, rq, dp, bp = t(root_pos), t(root_quat), t(dof_pos), t(body_pos)
        n = rp.shape[0]
        parts = {  # every linearly interpolated quantity lives in one [T, D] tensor: one gather per query
            "root_pos": rp, "root_lin_vel": diff(rp),
            "root_ang_vel": _quat_log(quat_mul(rq[nxt], quat_conj(rq[prev]))) * inv[:, None],
            "dof_pos": dp, "dof_vel": diff(dp), "body_pos": bp.reshape(n, -1), "body_vel": diff(bp).reshape(n, -1),
        }
        self._flat = torch.cat(list(parts.values()), dim=1).to(dt).contiguous()
        self._slices: dict[str, slice] = {}
        i = 0
        for k, v in parts.items():
            self._slices[k] = slice(i, i + v.shape[1])
            i += v.shape[1]
        self.root_quat = rq.to(dt)
        """[T, 4] packed root quaternions (wxyz); the other packed fields are properties below."""

    def _field(self, name: str) -> torch.Tensor:
        x = self._flat[:, self._slices[name]]
        return x.view(x.shape[0], -1, 3) if name.startswith("body_") else x

    root_pos = property(lambda self: self._field("root_pos"), doc="[T, 3] packed root positions, m.")
    root_lin_vel = property(lambda self: self._field("root_lin_vel"), doc="[T, 3] m/s, world.")
    root_ang_vel = property(lambda self: self._field("root_ang_vel"), doc="[T, 3] rad/s, world.")
    dof_pos = property(lambda self: self._field("dof_pos"), doc="[T, 32] rad.")
    dof_vel = property(lambda self: self._field("dof_vel"), doc="[T, 32] rad/s.")
    body_pos = property(lambda self: self._field("body_pos"), doc="[T, 15, 3] m, world.")
    body_vel = property(lambda self: self._field("body_vel"), doc="[T, 15, 3] m/s, world.")

    # --- sampling -----------------------------------------------------------------------

    @property
    def num_clips(self) -> int:
        return len(self.clips)

    @property
    def skills_present(self) -> list[str]:
        return [s for s in MOTION_LABELS if any(c.skill == s for c in self.clips)]

    def set_skill_weights(self, skill_weights: dict[str, float] | None) -> None:
        """Set sampling probabilities per label (normalised; labels without clips are ignored)."""
        present = self.skills_present
        if skill_weights is None:
            skill_weights = {s: 1.0 for s in present}
        unknown = [k for k in skill_weights if k not in MOTION_LABELS]
        if unknown:
            raise ValueError(f"skill_weights: unknown skill(s) {', '.join(map(repr, unknown))}; "
                             f"expected some of {', '.join(MOTION_LABELS)}")
        bad = {k: v for k, v in skill_weights.items() if not (float(v) >= 0.0 and np.isfinite(float(v)))}
        if bad:
            raise ValueError(f"skill_weights: weights must be finite and >= 0, got {bad}")
        self.skill_weights = {s: float(skill_weights.get(s, 0.0)) for s in present}
        if sum(self.skill_weights.values()) <= 0.0:
            raise ValueError(f"skill_weights: no positive weight for the skills present ({', '.join(present)})")
        self._probs_cache: dict[tuple[str, ...], torch.Tensor] = {}

    def clip_probs(self, skills: Sequence[str] | str | None = None) -> torch.Tensor:
        """[C] probability of drawing each clip, optionally restricted to some labels (or to a
        single label); label weights are renormalised in the subset."""
        subset = _skill_subset(skills, self.skills_present)
        if subset not in self._probs_cache:
            w = np.zeros(self.num_clips)
            for s in subset:
                members = [i for i, c in enumerate(self.clips) if c.skill == s]
                share = np.array([self.clips[i].duration if self.weight_by_length else 1.0 for i in members])
                share = share / share.sum() if share.sum() > 0 else np.full(len(members), 1.0 / len(members))
                w[members] = self.skill_weights[s] * share
            if w.sum() <= 0.0:
                raise ValueError(f"no clips with positive weight for skills {list(subset)}")
            self._probs_cache[subset] = torch.as_tensor(w / w.sum(), dtype=torch.float64, device=self.device)
        return self._probs_cache[subset]

    def sample_clips(self, n: int, skills: Sequence[str] | str | None = None,
                     generator: torch.Generator | None = None) -> torch.Tensor:
        """[n] clip ids drawn with replacement according to `clip_probs(skills)`."""
        return torch.multinomial(self.clip_probs(skills), n, replacement=True, generator=generator)

    def sample_times(self, clip_ids: torch.Tensor, truncate_s: float = 0.0,
                     generator: torch.Generator | None = None) -> torch.Tensor:
        """[n] times (s) uniform in [0, length - truncate_s] of each clip (0 if it is shorter)."""
        u = torch.rand(clip_ids.shape, generator=generator, device=self.device, dtype=self.dtype)
        return u * (self.clip_length[clip_ids] - truncate_s).clamp_min(0.0)

    def sample_windows(self, n: int, steps: int = 10, dt: float = 1.0 / 30.0,
                       skills: Sequence[str] | str | None = None,
                       generator: torch.Generator | None = None) -> tuple[torch.Tensor, MotionState]:
        """(clip ids [n], windows [n, steps, ...]) of random AMP reference windows; the window
        end is drawn so that the whole window lies inside the clip when the clip is long enough."""
        ids = self.sample_clips(n, skills, generator)
        span = dt * (steps - 1)
        end = self.sample_times(ids, span, generator) + torch.minimum(self.clip_length[ids],
                                                                        torch.full_like(self.clip_length[ids], span))
        return ids, self.windows(ids, end, steps, dt)

    # --- queries ------------------------------------------------------------------------

    def state(self, clip_ids: torch.Tensor, times: torch.Tensor) -> MotionState:
        """States [N] at `times` (s, clamped to [0, length]) of clips `clip_ids` (long [N])."""
        clip_ids = clip_ids.to(self.device, torch.long).reshape(-1)
        times = torch.as_tensor(times, device=self.device).reshape(-1)
        frames = self.clip_frames[clip_ids]
        ft = (times.to(torch.float64) * self.clip_fps[clip_ids]).clamp(min=0.0)
        ft = torch.minimum(ft, (frames - 1).to(torch.float64))
        f0 = torch.minimum(ft.floor().long(), (frames - 2).clamp_min(0))
        f1 = torch.minimum(f0 + 1, frames - 1)
        w = (ft - f0).clamp(0.0, 1.0).to(self.dtype)
        g0, g1 = self.clip_start[clip_ids] + f0, self.clip_start[clip_ids] + f1

        a, b = self._flat[g0], self._flat[g1]
        x = a + (b - a) * w[:, None]
        f = lambda k: x[:, self._slices[k]]  # noqa: E731
        body_pos = f("body_pos").reshape(-1, len(BODY_NAMES), 3)
        return MotionState(
            root_pos=f("root_pos"), root_quat=_slerp(self.root_quat[g0], self.root_quat[g1], w),
            root_lin_vel=f("root_lin_vel"), root_ang_vel=f("root_ang_vel"),
            dof_pos=f("dof_pos"), dof_vel=f("dof_vel"), body_pos=body_pos,
            body_vel=f("body_vel").reshape(-1, len(BODY_NAMES), 3), key_body_pos=body_pos[:, self.key_body_ids])

    def windows(self, clip_ids: torch.Tensor, end_times: torch.Tensor, steps: int = 10,
                dt: float = 1.0 / 30.0) -> MotionState:
        """States [N, steps, ...] at end_times - dt * (steps - 1 - k), k = 0..steps-1 (oldest
        first, the last one at end_times); times before 0 repeat the first frame."""
        n = clip_ids.shape[0]
        back = dt * torch.arange(steps - 1, -1, -1, device=self.device, dtype=torch.float64)
        t = torch.as_tensor(end_times, device=self.device).to(torch.float64).reshape(n, 1) - back
        ids = clip_ids.to(self.device).reshape(n, 1).expand(n, steps)
        return self.state(ids.reshape(-1), t.reshape(-1)).reshape_batch(n, steps)

    def __repr__(self) -> str:
        return (f"MotionLib({self.num_clips} clips, {int(self.clip_frames.sum())} frames, "
                f"{float(self.clip_length.sum()):.1f} s, skills {self.skill_weights}, device={self.device})")


def _gather(src) -> list[MotionClip]:
    if isinstance(src, (MotionClip, str, os.PathLike)):
        src = [src]
    out: list[MotionClip] = []
    for item in src:
        if isinstance(item, MotionClip):
            item.validate(f"clip {item.name!r}")
            out.append(item)
        elif Path(item).is_dir():
            out.extend(load_clips(item))
        else:
            out.append(load_clip(item))
    return out


def _skill_subset(skills, present: list[str]) -> tuple[str, ...]:
    if skills is None:
        return tuple(present)
    if isinstance(skills, str):
        skills = [skills]
    unknown = [s for s in skills if s not in MOTION_LABELS]
    if unknown:
        raise ValueError(f"unknown skill label(s) {', '.join(map(repr, unknown))}; expected labels from "
                         f"{', '.join(MOTION_LABELS)}")
    return tuple(s for s in MOTION_LABELS if s in skills and s in present)


def _slerp(q0: torch.Tensor, q1: torch.Tensor, w: torch.Tensor) -> torch.Tensor:
    """Shortest-path slerp of wxyz quaternions [N, 4] at fractions w [N]."""
    d = (q0 * q1).sum(-1, keepdim=True)
    q1 = torch.where(d < 0, -q1, q1)
    d = d.abs().clamp(max=1.0)
    theta = torch.acos(d)
    s = torch.sin(theta)
    w = w.view(-1, 1)
    small = s < 1e-6
    s_safe = torch.where(small, torch.ones_like(s), s)
    a = torch.where(small, 1.0 - w, torch.sin((1.0 - w) * theta) / s_safe)
    b = torch.where(small, w, torch.sin(w * theta) / s_safe)
    q = a * q0 + b * q1
    return q / q.norm(dim=-1, keepdim=True)


def _quat_log(q: torch.Tensor) -> torch.Tensor:
    """Rotation vector (axis * angle, rad) [N, 3] of wxyz quaternions [N, 4], shortest path."""
    q = torch.where(q[:, :1] < 0, -q, q)
    v = q[:, 1:]
    n = v.norm(dim=-1, keepdim=True)
    scale = torch.where(n > 1e-9, 2.0 * torch.atan2(n, q[:, :1]) / n.clamp_min(1e-12), 2.0 / q[:, :1].clamp_min(1e-12))
    return v * scale
