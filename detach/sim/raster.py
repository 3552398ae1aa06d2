"""The static height raster of a compiled scene on the env's device, sampled in batches."""

from __future__ import annotations

import math

import torch
import torch.nn.functional as F


class Raster:
    """A static height raster on the env's device, sampled bilinearly with `grid_sample`
    (0 = floor outside it). heights[i, j] is at (origin_x + i * spacing, origin_y + j * spacing)."""

    def __init__(self, heights: torch.Tensor, origin: tuple[float, float], spacing: float) -> None:
        self.img = heights[None, None].float()
        nx, ny = heights.shape
        dev = heights.device
        # world (x, y) -> grid_sample's (u, v) in [-1, 1]: u indexes columns (y), v rows (x)
        self.su, self.sv = 2.0 / (spacing * max(ny - 1, 1)), 2.0 / (spacing * max(nx - 1, 1))
        self.ou, self.ov = origin[1], origin[0]
        self.scale = torch.tensor([self.su, self.sv], device=dev)
        self.shift = torch.tensor([origin[1] * self.su + 1.0, origin[0] * self.sv + 1.0], device=dev)

    def sample_uv(self, uv: torch.Tensor) -> torch.Tensor:
        out = F.grid_sample(self.img, uv.reshape(1, -1, 1, 2), mode="bilinear", padding_mode="zeros",
                            align_corners=True)
        return out.reshape(uv.shape[:-1])

    def sample(self, xy: torch.Tensor) -> torch.Tensor:
        """Heights [...] at world points xy [..., 2]."""
        return self.sample_uv(xy.flip(-1) * self.scale - self.shift)

    def highest_within(self, xy: torch.Tensor, radius: float, directions: int) -> torch.Tensor:
        """Highest surface [n] (m) at points xy [n, 2] and at `directions` points evenly around
        each, `radius` m away (the first along +x): where feet of that reach stand."""
        ang = torch.linspace(0, 2 * math.pi, directions + 1, device=xy.device)[:-1]
        ring = radius * torch.stack((ang.cos(), ang.sin()), -1)
        return self.sample(torch.cat((xy[:, None], xy[:, None] + ring[None]), 1)).max(dim=-1).values
