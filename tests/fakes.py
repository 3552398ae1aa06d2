"""Small stand-ins shared by tests: a point-mass VecEnv with the contract's groups."""

from __future__ import annotations

import torch
from rsl_rl.env import VecEnv
from tensordict import TensorDict


class PointMassEnv(VecEnv):
    """2-D point mass that should move to the origin; `amp` is a 2-step window of its state."""

    def __init__(self, num_envs: int = 16, device: str = "cpu") -> None:
        self.num_envs, self.num_actions, self.max_episode_length = num_envs, 2, 50
        self.device, self.cfg = device, {}
        self.pos = torch.randn(num_envs, 2) * 2
        self.prev = self.pos.clone()
        self.episode_length_buf = torch.zeros(num_envs, dtype=torch.long)

    def get_observations(self) -> TensorDict:
        window = torch.cat([self.prev, self.pos], dim=-1)
        return TensorDict({"self": self.pos.clone(), "env": -self.pos.clone(),
                           "task": torch.nn.functional.one_hot(
                               torch.zeros(self.num_envs, dtype=torch.long), 4).float(),
                           "critic": self.pos.clone(), "amp": window},
                          batch_size=[self.num_envs])

    def step(self, actions: torch.Tensor):
        self.prev = self.pos.clone()
        self.pos = self.pos + 0.1 * actions.clamp(-1, 1)
        reward = torch.exp(-self.pos.norm(dim=-1))
        self.episode_length_buf += 1
        time_outs = self.episode_length_buf >= self.max_episode_length
        ids = time_outs.nonzero().flatten()
        self.pos[ids] = torch.randn(len(ids), 2) * 2
        self.prev[ids] = self.pos[ids]
        self.episode_length_buf[ids] = 0
        extras = {"time_outs": time_outs, "log": {"Episode_Success/follow": (reward > 0.8).float().mean()}}
        return self.get_observations(), reward, time_outs, extras
