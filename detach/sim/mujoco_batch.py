"""`mujoco.batch.Batch` as a `PhysicsBackend`: the CPU backend (all cores, GIL released)."""

from __future__ import annotations

import warnings

import mujoco
import numpy as np
import torch
from mujoco import batch as mjbatch

from detach.sim.backend import PhysicsBackend

_STAGE_VEL = int(mujoco.mjtStage.mjSTAGE_VEL)
_STAGE_NONE = int(mujoco.mjtStage.mjSTAGE_NONE)


class MujocoBatchBackend(PhysicsBackend):
    """`mujoco.batch.Batch` on nthread CPU threads (0 = all cores).

    The batch is persistent (one MjData per simulation) and every step ends with the
    position and velocity stages at the new state (`mjSTAGE_VEL`), which a persistent batch
    reuses for its next step: body poses and velocities are those of the current state at no
    extra cost. Views are converted to float32 torch tensors lazily, once per step.
    """

    _OUTPUTS = ("xpos", "xquat", "cvel", "subtree_com", "qfrc_actuator", "cfrc_ext", "ncon")

    def __init__(self, model: mujoco.MjModel, num_envs: int, nthread: int = 0,
                 device: str | torch.device = "cpu") -> None:
        self.model = model
        self.num_envs = int(num_envs)
        self.device = torch.device(device)
        self.batch = mjbatch.Batch(model, self.num_envs, nthread=nthread, persistent=True)
        self._np = {name: self.batch.bind(name) for name in ("qpos", "qvel", "ctrl", "eq_active")}
        for name in self._OUTPUTS:
            self._np[name] = self.batch.bind(name)
        self._eq_data = self.batch.expand("eq_data") if model.neq else None
        self._cache: dict[str, torch.Tensor] = {}
        self.batch.reset(stage=int(mujoco.mjtStage.mjSTAGE_ACC))

    @property
    def nthread(self) -> int:
        return self.batch.nthread

    def _view(self, name: str) -> torch.Tensor:
        t = self._cache.get(name)
        if t is None:
            arr = self._np[name]
            with warnings.catch_warnings():
                warnings.simplefilter("ignore")  # read-only outputs: we never write them
                src = torch.from_numpy(np.asarray(arr))
            dtype = torch.int32 if name == "ncon" else torch.float32
            t = src.to(device=self.device, dtype=dtype, copy=True)
            self._cache[name] = t
        return t

    def set_body_wrench(self, body_id: int, wrench: torch.Tensor) -> None:
        if "xfrc_applied" not in self._np:
            self._np["xfrc_applied"] = self.batch.bind("xfrc_applied")
        self._np["xfrc_applied"][:, body_id] = wrench.detach().to("cpu", torch.float64).numpy()

    def step(self, ctrl: torch.Tensor, nstep: int) -> None:
        self._np["ctrl"][:] = ctrl.detach().to("cpu", torch.float64).numpy()
        self.batch.step(nstep=int(nstep), stage=_STAGE_VEL)
        self._cache.clear()

    def reset(self, ids: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor) -> None:
        if len(ids) == 0:
            return
        idx = np.sort(ids.detach().cpu().numpy().astype(np.int64))
        order = np.argsort(ids.detach().cpu().numpy(), kind="stable")
        self.batch.reset(idx, stage=_STAGE_NONE)
        self._np["qpos"][idx] = qpos.detach().cpu().double().numpy()[order]
        self._np["qvel"][idx] = qvel.detach().cpu().double().numpy()[order]
        self.batch.forward(idx, stage=_STAGE_VEL)
        self._cache.clear()

    def forward(self, ids: torch.Tensor | None = None) -> None:
        """Recompute derived fields after writing state directly (tests, tools)."""
        idx = None if ids is None else np.sort(ids.detach().cpu().numpy().astype(np.int64))
        self.batch.forward(idx, stage=_STAGE_VEL)
        self._cache.clear()

    def set_equality(self, mask: torch.Tensor, eq_id: int, active: torch.Tensor,
                     data: torch.Tensor | None = None) -> None:
        m = mask.detach().cpu().numpy().astype(bool)
        if not m.any():
            return
        if data is not None:
            self._eq_data[m, eq_id] = data.detach().cpu().double().numpy()[m]
        self._np["eq_active"][m, eq_id] = active.detach().cpu().double().numpy()[m]
        self._cache.pop("eq_active", None)

    def write_qpos(self, ids: torch.Tensor, qpos: torch.Tensor) -> None:
        """Overwrite qpos of simulations ids without resetting anything else (tests, tools)."""
        idx = ids.detach().cpu().numpy().astype(np.int64)
        self._np["qpos"][idx] = qpos.detach().cpu().double().numpy()
        self.forward(ids)

    def get_data(self, env: int) -> mujoco.MjData:
        """One simulation's full MjData (rendering, recording, debugging)."""
        return self.batch.get_data(int(env))

    qpos = property(lambda self: self._view("qpos"))
    qvel = property(lambda self: self._view("qvel"))
    xpos = property(lambda self: self._view("xpos"))
    xquat = property(lambda self: self._view("xquat"))
    cvel = property(lambda self: self._view("cvel"))
    subtree_com = property(lambda self: self._view("subtree_com"))
    qfrc_actuator = property(lambda self: self._view("qfrc_actuator"))
    cfrc_ext = property(lambda self: self._view("cfrc_ext"))
    ncon = property(lambda self: self._view("ncon"))
    eq_active = property(lambda self: self._view("eq_active"))
