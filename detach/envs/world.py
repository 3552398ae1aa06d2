"""The simulated world of an env: its character, compiled scene and physics backend.

Built once per env from the task, the character and the sim settings: the scene compiled with
the character into one MjModel, N copies of it in a backend (`detach.sim`), the indices that
read bodies and objects out of the backend's state, and the character bound to its movable
objects (the puppet's grasp welds). Task logic sees the world through `read()`, a `SimState`.
"""

from __future__ import annotations

from dataclasses import dataclass

import mujoco
import torch

from detach.character import Character, MovableObject, make_character
from detach.config.schema import RunConfig, SimCfg
from detach.envs.assist import BalanceAssist
from detach.sim import PhysicsBackend, make_backend
from detach.sim.raster import Raster
from detach.sim.state import SceneIndex, SimState, read_state
from scene_builder.scene import SceneInfo, compile_scene


@dataclass(frozen=True)
class World:
    character: Character
    model: mujoco.MjModel
    scene: SceneInfo
    backend: PhysicsBackend
    index: SceneIndex
    raster: Raster
    """The static surface's heights (m) on the scene's grid, on the env's device."""
    dyn_slot: torch.Tensor
    """[K + 1] scene object index -> slot among the dynamic objects (-1: static; [-1]: none)."""
    assist: BalanceAssist
    """The training aid `train.balance_assist` (off unless the trainer sets it)."""

    @classmethod
    def build(cls, cfg: RunConfig, sim: SimCfg, num_envs: int, device: torch.device, assets: dict | None = None,
              assets_root=None) -> World:
        """The world of cfg's task with N = num_envs copies; sim: `sim_settings(cfg.sim)`."""
        character = make_character(cfg.env.character)
        model, scene = compile_scene(cfg.task, character, sim, assets, assets_root,
                                     camera_height=cfg.env.height_map.camera_height)
        backend = make_backend(sim, model, num_envs, device)
        index = SceneIndex.build(scene, device)
        objects = scene.objects
        movable = tuple(MovableObject(k, i, objects[i].link_eq, tuple(objects[i].bbox / 2))
                        for k, i in enumerate(scene.dynamic))
        character.bind(num_envs, device, backend, movable, index.hands, scene.root_qpos_adr)
        dyn_slot = torch.full((len(objects) + 1,), -1, dtype=torch.long, device=device)
        dyn_slot[torch.as_tensor(scene.dynamic, dtype=torch.long, device=device)] = torch.arange(
            len(scene.dynamic), device=device)
        r = scene.raster
        raster = Raster(torch.as_tensor(r.heights, device=device), r.origin, r.spacing)
        assist = BalanceAssist(backend, int(index.body[0]))
        return cls(character, model, scene, backend, index, raster, dyn_slot, assist)

    def read(self) -> SimState:
        """The backend's current state as bodies, hinges and objects (world frame)."""
        return read_state(self.backend, self.index)
