"""detach.sim: the physics seam. Batched simulators of one compiled scene behind
`PhysicsBackend`, chosen by `sim.backend`; one read of their state (`SimState`); the scene's
static height raster on torch.

Backends: `mujoco_batch` (CPU, `mujoco.batch.Batch` on all cores) and `warp` (MuJoCo Warp on
a GPU or warp's CPU device; the `[warp]` extra). Register another with
`register_backend(name, factory)`; `make_backend(sim_cfg, model, num_envs, device)` builds
the configured one. `sim_settings` fills the settings a backend decides (`sim.sleep: null`);
`check_sim` refuses a combination a backend cannot run, naming the key.
"""

from __future__ import annotations

import dataclasses
from dataclasses import dataclass
from typing import Callable

import mujoco
import torch

from detach.config.schema import SimCfg
from detach.sim.backend import PhysicsBackend

BackendFactory = Callable[[SimCfg, mujoco.MjModel, int, torch.device], PhysicsBackend]
BackendCheck = Callable[[SimCfg, str], "list[tuple[str, str]]"]
"""(sim config, torch device name) -> [(sim key, why)] of what the backend cannot run."""


class SimConfigError(ValueError):
    """A `sim` setting the chosen backend cannot run; `key` is the key under `sim`."""

    def __init__(self, key: str, message: str) -> None:
        super().__init__(message)
        self.key = key


@dataclass(frozen=True)
class BackendSpec:
    factory: BackendFactory
    sleep: bool = True
    """What `sim.sleep: null` means with this backend."""
    check: BackendCheck | None = None


def _mujoco_batch(cfg: SimCfg, model: mujoco.MjModel, num_envs: int, device: torch.device) -> PhysicsBackend:
    from detach.sim.mujoco_batch import MujocoBatchBackend

    return MujocoBatchBackend(model, num_envs, cfg.nthread, device)


def _warp(cfg: SimCfg, model: mujoco.MjModel, num_envs: int, device: torch.device) -> PhysicsBackend:
    from detach.sim.warp_backend import WarpBackend

    return WarpBackend(model, num_envs, device, nconmax=cfg.nconmax, njmax=cfg.njmax, cuda_graph=cfg.cuda_graph)


def _check_warp(cfg: SimCfg, device: str) -> list[tuple[str, str]]:
    from detach.sim.warp_backend import warp_available

    problems = []
    if not (device == "cpu" or device.startswith("cuda")):
        problems.append(("backend", f"the warp backend runs on cpu or cuda devices, not '{device}'"))
    if cfg.sleep:
        problems.append(("sleep", "the warp backend does not support sleeping (fresh LH worlds went non-finite "
                                  "after one step with it, mujoco-warp 4.0.0); set sim.sleep=false or null"))
    if not problems:
        why = warp_available()  # imports warp: only once the settings are known to be fine
        if why is not None:
            problems.append(("backend", why))
    return problems


BACKENDS: dict[str, BackendFactory] = {}
SPECS: dict[str, BackendSpec] = {}


def register_backend(name: str, factory: BackendFactory, *, sleep: bool = True,
                     check: BackendCheck | None = None) -> None:
    """Add a backend: its factory, what `sim.sleep: null` means with it, and an optional check
    of the `sim` settings it cannot run."""
    BACKENDS[name] = factory
    SPECS[name] = BackendSpec(factory, sleep, check)


register_backend("mujoco_batch", _mujoco_batch)
register_backend("warp", _warp, sleep=False, check=_check_warp)


def backend_names() -> tuple[str, ...]:
    return tuple(BACKENDS)


def check_backend(name: str) -> None:
    """ValueError naming the available backends when `name` is not one of them."""
    if name not in BACKENDS:
        raise ValueError(f"unknown physics backend '{name}'; available: {', '.join(BACKENDS)}")


def sim_settings(cfg: SimCfg) -> SimCfg:
    """`cfg` with the backend-decided settings filled in (`sleep: null` -> the backend's)."""
    check_backend(cfg.backend)
    if cfg.sleep is None:
        cfg = dataclasses.replace(cfg, sleep=SPECS[cfg.backend].sleep)
    return cfg


def check_sim(cfg: SimCfg, device: str = "cpu") -> None:
    """SimConfigError (the first problem, with its key under `sim`) when the backend cannot run
    these settings on `device`."""
    check_backend(cfg.backend)
    check = SPECS[cfg.backend].check
    for key, why in (check(sim_settings(cfg), str(device)) if check else []):
        raise SimConfigError(key, why)


def make_backend(cfg: SimCfg, model: mujoco.MjModel, num_envs: int, device: torch.device) -> PhysicsBackend:
    check_backend(cfg.backend)
    return BACKENDS[cfg.backend](sim_settings(cfg), model, num_envs, torch.device(device))


__all__ = ["BACKENDS", "PhysicsBackend", "SimConfigError", "backend_names", "check_backend", "check_sim",
           "make_backend", "register_backend", "sim_settings"]
