"""detach.sim: the physics seam. Batched simulators of one compiled scene behind
`PhysicsBackend`, chosen by `sim.backend`; one read of their state (`SimState`); the scene's
static height raster on torch.

Backends: `mujoco_batch` (CPU, `mujoco.batch.Batch` on all cores). Register another with
`register_backend(name, factory)`; `make_backend(sim_cfg, model, num_envs, device)` builds
the configured one.
"""

from __future__ import annotations

from typing import Callable

import mujoco
import torch

from detach.config_schema import SimCfg
from detach.sim.backend import PhysicsBackend

BackendFactory = Callable[[SimCfg, mujoco.MjModel, int, torch.device], PhysicsBackend]


def _mujoco_batch(cfg: SimCfg, model: mujoco.MjModel, num_envs: int, device: torch.device) -> PhysicsBackend:
    from detach.sim.mujoco_batch import MujocoBatchBackend

    return MujocoBatchBackend(model, num_envs, cfg.nthread, device)


BACKENDS: dict[str, BackendFactory] = {"mujoco_batch": _mujoco_batch}


def register_backend(name: str, factory: BackendFactory) -> None:
    BACKENDS[name] = factory


def backend_names() -> tuple[str, ...]:
    return tuple(BACKENDS)


def check_backend(name: str) -> None:
    """ValueError naming the available backends when `name` is not one of them."""
    if name not in BACKENDS:
        raise ValueError(f"unknown physics backend '{name}'; available: {', '.join(BACKENDS)}")


def make_backend(cfg: SimCfg, model: mujoco.MjModel, num_envs: int, device: torch.device) -> PhysicsBackend:
    check_backend(cfg.backend)
    return BACKENDS[cfg.backend](cfg, model, num_envs, torch.device(device))


__all__ = ["BACKENDS", "PhysicsBackend", "backend_names", "check_backend", "make_backend", "register_backend"]
