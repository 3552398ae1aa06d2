"""The seam between task logic and the physics engine (docs/ARCHITECTURE.md, "Physics backend").

Task code sees N independent simulations of one MjModel through `PhysicsBackend`: it writes
controls, steps, resets chosen simulations to given states, and reads batched state as torch
tensors on its device. It never touches MjData. `detach.sim.mujoco_batch.MujocoBatchBackend`
is the CPU implementation on `mujoco.batch.Batch`; `detach.sim.make_backend` picks the one
named by `sim.backend`.

All tensors are float32 on `device`, world frame, MuJoCo conventions: quaternions wxyz,
`cvel` = [angular(3), linear(3)] spatial velocity about `subtree_com` of the body's tree root,
`cfrc_ext` = [torque(3), force(3)] of external (contact) forces on each body.
"""

from __future__ import annotations

from abc import ABC, abstractmethod

import mujoco
import torch


class PhysicsBackend(ABC):
    """Batched simulator of one model; every view is [N, ...] and current after step/reset."""

    model: mujoco.MjModel
    num_envs: int
    device: torch.device

    @abstractmethod
    def step(self, ctrl: torch.Tensor, nstep: int) -> None:
        """Apply ctrl [N, nu] and advance every simulation by nstep physics steps."""

    @abstractmethod
    def reset(self, ids: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor) -> None:
        """Reset simulations ids [n] to model defaults, then to the given qpos [n, nq], qvel [n, nv].

        Controls, equality activations and warm starts return to the model's defaults.
        """

    @abstractmethod
    def set_equality(self, mask: torch.Tensor, eq_id: int, active: torch.Tensor,
                     data: torch.Tensor | None = None) -> None:
        """Switch equality constraint eq_id on/off (active [N]) in the simulations where mask
        [N] is set; optionally set its per-simulation eq_data [N, 12] (e.g. a weld's relative
        pose). Rows outside mask are ignored: a mask needs no host read to select them."""

    def set_body_wrench(self, body_id: int, wrench: torch.Tensor) -> None:
        """Hold an external wrench [N, 6] (world-frame force, then torque; MuJoCo's
        `xfrc_applied`) on body `body_id` from the next step until it is set again; a reset
        clears it in the reset simulations."""
        raise NotImplementedError(f"{type(self).__name__} applies no external wrench")

    # batched views ------------------------------------------------------------------------
    @property
    @abstractmethod
    def qpos(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def qvel(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def xpos(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def xquat(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def cvel(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def subtree_com(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def qfrc_actuator(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def cfrc_ext(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def ncon(self) -> torch.Tensor: ...

    @property
    @abstractmethod
    def eq_active(self) -> torch.Tensor: ...

    def body_velocities(self) -> tuple[torch.Tensor, torch.Tensor]:
        """(linear velocity of each body origin, angular velocity), world frame, [N, nbody, 3]:
        `cvel` moved from its tree root's centre of mass to the body origin."""
        cvel = self.cvel
        root = getattr(self, "_body_rootid", None)
        if root is None:
            root = self._body_rootid = torch.as_tensor(self.model.body_rootid, device=self.device, dtype=torch.long)
        com = self.subtree_com[:, root]
        ang, lin = cvel[..., :3], cvel[..., 3:]
        return lin + torch.cross(ang, self.xpos - com, dim=-1), ang
