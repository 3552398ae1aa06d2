"""Where each observation group sits in the flat model input, and how to reshape it.

rsl-rl hands a model the groups of its observation set (e.g. actor: self, env, task); the
model concatenates them (so rsl-rl's EmpiricalNormalization can normalise them in one go) and
`ObsLayout.split` cuts the normalised vector back into named pieces, reshaping the history
groups `self` and `env` from [N, T*d] to [N, T, d] (time-major, step 0 oldest; see
`detach.envs.obs_spec`). Groups other than self/env/task (e.g. `critic`) stay flat.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F
from tensordict import TensorDict

from detach.envs.obs_spec import ObsSpec

HISTORY_GROUPS: tuple[str, ...] = ("self", "env")


@dataclass(frozen=True)
class ObsLayout:
    """Names, widths and history shapes of the groups one model consumes, in input order."""

    groups: tuple[str, ...]
    dims: tuple[int, ...]
    spec: ObsSpec

    @classmethod
    def from_obs(cls, obs: TensorDict, groups: list[str] | tuple[str, ...], spec: ObsSpec) -> ObsLayout:
        """Check every group's width against the spec and record the order."""
        expected = spec.group_dims()
        dims = []
        for g in groups:
            if g not in obs.keys():
                raise KeyError(f"observation group '{g}' is missing; the TensorDict has {list(obs.keys())}")
            width = obs[g].shape[-1]
            if g in expected and width != expected[g]:
                raise ValueError(f"observation group '{g}' has width {width}, obs_spec expects {expected[g]}")
            dims.append(int(width))
        return cls(tuple(groups), tuple(dims), spec)

    def require(self, *names: str) -> None:
        """One-line error when a model needs a group its observation set lacks."""
        missing = [n for n in names if n not in self.groups]
        if missing:
            raise ValueError(f"model needs observation groups {missing}; its obs set has {list(self.groups)}")

    def history_shape(self, group: str) -> tuple[int, int]:
        """(T, d) of a history group."""
        if group == "self":
            return self.spec.self_steps, self.spec.self_dim
        if group == "env":
            return self.spec.env_steps, self.spec.env_dim
        raise KeyError(group)

    @property
    def extra_groups(self) -> tuple[str, ...]:
        """Flat groups beyond self/env/task (e.g. the privileged `critic` group)."""
        return tuple(g for g in self.groups if g not in (*HISTORY_GROUPS, "task"))

    def dim(self, group: str) -> int:
        return self.dims[self.groups.index(group)]

    def columns(self, group: str) -> torch.Tensor:
        """Flat input indices of `group` as its layers read them: [d, T] for a history (column
        c of frame t at [c, t]), [D, 1] for a flat group (the models' `input_weights`)."""
        i = self.groups.index(group)
        start = sum(self.dims[:i])
        if group in HISTORY_GROUPS:
            t, d = self.history_shape(group)
            return start + torch.arange(t * d).reshape(t, d).T
        return start + torch.arange(self.dims[i])[:, None]

    def split(self, x: torch.Tensor) -> dict[str, torch.Tensor]:
        """[N, sum(dims)] -> {group: [N, T, d] for histories, [N, D] otherwise}."""
        out: dict[str, torch.Tensor] = {}
        for g, part in zip(self.groups, torch.split(x, list(self.dims), dim=-1)):
            if g in HISTORY_GROUPS:
                t, d = self.history_shape(g)
                part = part.reshape(*part.shape[:-1], t, d)
            out[g] = part
        return out


def align_time(x: torch.Tensor, steps: int) -> torch.Tensor:
    """Resample a sequence [N, T, d] to [N, steps, d] (identity when T == steps).

    Used where a per-time-step pairing of self and env features is needed and the two
    histories have different lengths: linear interpolation, oldest and newest steps aligned.
    """
    if x.shape[1] == steps:
        return x
    y = F.interpolate(x.transpose(1, 2), size=steps, mode="linear", align_corners=True)
    return y.transpose(1, 2)


def stack_columns(*parts: torch.Tensor) -> torch.Tensor:
    """Concatenate column maps [k_i, F_i] along k, padding the frame axis with -1 (no input)."""
    width = max((p.shape[1] for p in parts), default=1)
    return torch.cat([F.pad(p, (0, width - p.shape[1]), value=-1) for p in parts])


def no_columns(k: int) -> torch.Tensor:
    """Column map [k, 1] of k features that are no input of the model's (computed ones)."""
    return torch.full((k, 1), -1, dtype=torch.long)
