"""MuJoCo Warp (`mujoco_warp`) as a `PhysicsBackend`: N worlds of one model on a GPU, or on
warp's CPU device (tests, machines without a GPU). Optional: `pip install -e '.[warp]'`.

What it keeps of the contract (`detach.sim.backend`):

- views are zero-copy torch tensors of the warp arrays (`wp.to_torch`), float32, the same
  memory the kernels write: nothing is copied per step, except `eq_active` (bool in warp,
  float32 in the contract) and `ncon` (counted per world from the shared contact buffer);
- `step(ctrl, nstep)` runs exactly `nstep` `mujoco_warp.step` calls, then the kinematics,
  the centre-of-mass velocities and collision at the new state, so that, as with the CPU
  backend, body poses, velocities and contacts are those of the current state, while
  `qfrc_actuator` and `cfrc_ext` are those of the last physics step;
- `reset(ids, ...)` resets the chosen worlds by a mask (`mujoco_warp.reset_data`), writes
  their state and recomputes them; `set_equality` writes per-world `eq_active` and `eq_data`
  (the model's `eq_data` is batched per world);
- on a CUDA device the `nstep` steps and the recomputation are one CUDA graph, captured on the
  first step and replayed after; warp's stream waits for torch's before it and torch's for
  warp's after it, so torch code may read and write the views in its own stream order.

No call here synchronises the host with the device, except an overflow check every
`OVERFLOW_CHECK_EVERY` control steps (one small read): a world that needs more contacts or
constraint rows than `sim.nconmax` / `sim.njmax` raises `WarpCapacityError` naming the key.

Sleeping (`sim.sleep`) is refused by `check_config`: with it on, fresh worlds of the LH
scenes were measured to go non-finite after one step (mujoco-warp 4.0.0).
"""

from __future__ import annotations

import os
from pathlib import Path

import mujoco
import numpy as np
import torch

from detach.sim.backend import PhysicsBackend

OVERFLOW_CHECK_EVERY = 64
"""Control steps between two reads of warp's overflow flags (the only host read per step)."""

_JMAX_BITS = (1 << 0) | (1 << 1)
"""mujoco_warp OverflowType NEFC and NJMAX_NNZ: constraint rows (`sim.njmax`)."""
_CAPACITY_BITS = _JMAX_BITS | (1 << 2) | (1 << 3) | (1 << 4)
"""... and BROADPHASE, NARROWPHASE, CCD: contacts (`sim.nconmax`). The solver's iteration-limit
bits are not capacity: with 4 iterations they are set on most steps."""

_CONTRACT_VIEWS = ("qpos", "qvel", "xpos", "xquat", "cvel", "subtree_com", "qfrc_actuator", "cfrc_ext")


class WarpCapacityError(RuntimeError):
    """A world overflowed the contact or constraint buffers (`sim.nconmax`, `sim.njmax`)."""


def kernel_cache_dir() -> Path:
    """Where warp keeps compiled kernels: `$WARP_CACHE_PATH`, else a folder under the user
    cache (`$XDG_CACHE_HOME` or ~/.cache) / detach / warp. A cold compile of mujoco_warp's
    kernels on a CPU takes minutes; a warm one seconds."""
    env = os.environ.get("WARP_CACHE_PATH")
    if env:
        return Path(env)
    base = os.environ.get("XDG_CACHE_HOME") or os.path.join(os.path.expanduser("~"), ".cache")
    return Path(base) / "detach" / "warp"


def import_warp():
    """(warp, mujoco_warp), initialised with the kernel cache of `kernel_cache_dir`; ImportError
    naming the extra when they are not installed."""
    try:
        import warp as wp
        import mujoco_warp as mjw
    except ImportError as exc:
        raise ImportError(f"the warp backend needs mujoco-warp and warp-lang: pip install -e '.[warp]' "
                          f"({exc})") from None
    if not getattr(wp, "_detach_initialised", False):
        if wp.config.kernel_cache_dir is None:
            wp.config.kernel_cache_dir = str(kernel_cache_dir())
        wp.config.log_level = wp.LOG_WARNING  # no banner, no per-module load lines
        wp.init()
        wp._detach_initialised = True
    return wp, mjw


def warp_available() -> str | None:
    """None when the warp backend can be used here, else why not (one line)."""
    try:
        import_warp()
    except ImportError as exc:
        return str(exc)
    return None


def warp_device_name(device: torch.device) -> str:
    """torch device -> warp device ('cpu', 'cuda:N')."""
    if device.type == "cpu":
        return "cpu"
    if device.type == "cuda":
        return f"cuda:{device.index if device.index is not None else torch.cuda.current_device()}"
    raise ValueError(f"the warp backend runs on cpu or cuda devices, not '{device}'")


class WarpBackend(PhysicsBackend):
    """N worlds of `model` in mujoco_warp on `device` (see the module docstring)."""

    def __init__(self, model: mujoco.MjModel, num_envs: int, device: str | torch.device = "cpu",
                 nconmax: int = 128, njmax: int = 256, cuda_graph: bool | None = None) -> None:
        if model.opt.enableflags & int(mujoco.mjtEnableBit.mjENBL_SLEEP):
            raise ValueError("the warp backend does not support sleeping (sim.sleep); compile the model "
                             "with sleep off")
        wp, mjw = import_warp()
        self.wp, self.mjw = wp, mjw
        self.model = model
        self.num_envs = n = int(num_envs)
        self.device = torch.device(device)
        self.wp_device = wp.get_device(warp_device_name(self.device))
        if self.wp_device.is_cuda and self.device.index is None:
            self.device = torch.device("cuda", self.wp_device.ordinal)
        self.nconmax, self.njmax = int(nconmax), int(njmax)
        with wp.ScopedDevice(self.wp_device):
            self.m = mjw.put_model(model, batch_sizes={"eq_data": n} if model.neq else None)
            # print only capacity overflows: the solver's iteration limit is hit on most steps
            # with the project's 4 iterations (a kernel-compile-time setting)
            self.m.opt.warn_overflow = _CAPACITY_BITS
            self.d = mjw.make_data(model, nworld=n, nconmax=self.nconmax, njmax=self.njmax)
        self._t = {name: wp.to_torch(getattr(self.d, name)) for name in _CONTRACT_VIEWS}
        self._ctrl = wp.to_torch(self.d.ctrl)
        self._xfrc: torch.Tensor | None = None
        self._eq_active = wp.to_torch(self.d.eq_active) if model.neq else None
        self._eq_data = wp.to_torch(self.m.eq_data) if model.neq else None
        self._nacon = wp.to_torch(self.d.nacon)
        self._con_world = wp.to_torch(self.d.contact.worldid)
        self._overflow = wp.to_torch(self.d.overflow)
        self._overflow_seen = torch.zeros_like(self._overflow)
        self._slots = torch.arange(self._con_world.shape[0], device=self.device)
        self._mask = torch.zeros(n, dtype=torch.bool, device=self.device)
        self._mask_wp = wp.from_torch(self._mask, dtype=wp.bool)
        self._cache: dict[str, torch.Tensor] = {}
        self._since_check = 0
        self.cuda_graph = self.wp_device.is_cuda if cuda_graph is None else bool(cuda_graph and self.wp_device.is_cuda)
        self._graphs: dict[int, object] = {}
        self._run(lambda: mjw.reset_data(self.m, self.d))
        self._run(self._recompute)

    # ------------------------------------------------------------------ launches
    def _run(self, fn) -> None:
        """fn's warp launches on warp's stream, ordered after torch's work and before torch's
        next work (CUDA); on the CPU device launches are synchronous."""
        wp = self.wp
        if not self.wp_device.is_cuda:
            with wp.ScopedDevice(self.wp_device):
                fn()
            return
        torch_stream = wp.stream_from_torch(torch.cuda.current_stream(self.device))
        warp_stream = wp.get_stream(self.wp_device)
        warp_stream.wait_stream(torch_stream)
        with wp.ScopedDevice(self.wp_device):
            fn()
        torch_stream.wait_stream(warp_stream)

    def _recompute(self) -> None:
        """Kinematics, centre-of-mass positions and velocities and contacts of the current
        state (what the CPU backend's `mjSTAGE_VEL` makes current)."""
        mjw = self.mjw
        mjw.fwd_kinematics(self.m, self.d)
        mjw.com_vel(self.m, self.d)
        mjw.collision(self.m, self.d)

    def _steps(self, nstep: int) -> None:
        for _ in range(nstep):
            self.mjw.step(self.m, self.d)
        self._recompute()

    def set_body_wrench(self, body_id: int, wrench: torch.Tensor) -> None:
        if self._xfrc is None:  # a view of the device array the captured graph reads
            self._xfrc = self.wp.to_torch(self.d.xfrc_applied)
        self._xfrc[:, body_id].copy_(wrench.detach())

    def step(self, ctrl: torch.Tensor, nstep: int) -> None:
        nstep = int(nstep)
        self._ctrl.copy_(ctrl.detach())
        graph = self._graphs.get(nstep)
        if graph is not None:
            self._run(lambda: self.wp.capture_launch(graph))
        else:
            self._run(lambda: self._steps(nstep))  # eagerly; on CUDA this also loads every kernel
            if self.cuda_graph:
                self._graphs[nstep] = self._capture(nstep)
        self._cache.clear()
        self._overflow_seen.bitwise_or_(self._overflow)  # reset_data clears a world's flags
        self._since_check += 1
        if self._since_check >= OVERFLOW_CHECK_EVERY:
            self.check_overflow()

    def _capture(self, nstep: int):
        """The launches of `_steps(nstep)` recorded as one CUDA graph (recorded, not run: the
        kernels were loaded by the eager step before)."""
        wp = self.wp
        with wp.ScopedDevice(self.wp_device), wp.ScopedCapture(device=self.wp_device) as capture:
            self._steps(nstep)
        return capture.graph

    def check_overflow(self) -> None:
        """WarpCapacityError when some world overflowed its buffers since the backend was
        made (one host read)."""
        self._since_check = 0
        bits = torch.bitwise_and(self._overflow_seen.bitwise_or_(self._overflow), _CAPACITY_BITS)
        if int(bits.amax().item()) == 0:
            return
        bits = bits.cpu().numpy()
        worlds = int(np.count_nonzero(bits))
        rows = bool(np.bitwise_or.reduce(bits) & _JMAX_BITS)
        key, now = ("sim.njmax", self.njmax) if rows else ("sim.nconmax", self.nconmax)
        raise WarpCapacityError(f"{worlds} of {self.num_envs} worlds overflowed the warp backend's "
                                f"{'constraint rows' if rows else 'contacts'}: raise {key} (now {now})")

    def reset(self, ids: torch.Tensor, qpos: torch.Tensor, qvel: torch.Tensor) -> None:
        ids = ids.to(self.device, torch.long)
        self._mask.zero_()
        self._mask.index_fill_(0, ids, True)  # `[ids] = True` would copy the True to the device
        mask = self._mask
        self._run(lambda: self.mjw.reset_data(self.m, self.d, reset=self._mask_wp))
        self._t["qpos"][ids] = qpos.to(self.device, torch.float32)
        self._t["qvel"][ids] = qvel.to(self.device, torch.float32)
        # mj_resetData zeroes every output; reset_data leaves these two to the next step
        self._t["qfrc_actuator"].masked_fill_(mask[:, None], 0.0)
        self._t["cfrc_ext"].masked_fill_(mask[:, None, None], 0.0)
        self._run(self._recompute)
        self._cache.clear()

    def set_equality(self, mask: torch.Tensor, eq_id: int, active: torch.Tensor,
                     data: torch.Tensor | None = None) -> None:
        mask = mask.to(self.device, torch.bool)
        if data is not None:
            self._eq_data[:, eq_id] = torch.where(mask[:, None], data.to(self.device, torch.float32),
                                                  self._eq_data[:, eq_id])
        self._eq_active[:, eq_id] = torch.where(mask, active.to(self.device).bool(), self._eq_active[:, eq_id])
        self._cache.pop("eq_active", None)

    def write_qpos(self, ids: torch.Tensor, qpos: torch.Tensor) -> None:
        """Overwrite qpos of worlds ids and recompute them (tests, tools)."""
        self._t["qpos"][ids.to(self.device, torch.long)] = qpos.to(self.device, torch.float32)
        self._run(self._recompute)
        self._cache.clear()

    def get_data(self, env: int) -> mujoco.MjData:
        """One world's state as an MjData (rendering, recording, debugging); reads the device."""
        data = mujoco.MjData(self.model)
        data.qpos[:] = self.qpos[env].double().cpu().numpy()
        data.qvel[:] = self.qvel[env].double().cpu().numpy()
        if self.model.neq:
            data.eq_active[:] = self._eq_active[env].cpu().numpy()
        mujoco.mj_forward(self.model, data)
        return data

    # ------------------------------------------------------------------ views
    def _derived(self, name: str) -> torch.Tensor:
        t = self._cache.get(name)
        if t is None:
            if name == "eq_active":
                t = self._eq_active.float() if self._eq_active is not None else \
                    torch.zeros(self.num_envs, 0, device=self.device)
            else:  # contacts per world, from the shared contact buffer
                valid = (self._slots < self._nacon).int()
                world = self._con_world.long().clamp(0, self.num_envs - 1)
                t = torch.zeros(self.num_envs, dtype=torch.int32, device=self.device).scatter_add_(0, world, valid)
            self._cache[name] = t
        return t

    qpos = property(lambda self: self._t["qpos"])
    qvel = property(lambda self: self._t["qvel"])
    xpos = property(lambda self: self._t["xpos"])
    xquat = property(lambda self: self._t["xquat"])
    cvel = property(lambda self: self._t["cvel"])
    subtree_com = property(lambda self: self._t["subtree_com"])
    qfrc_actuator = property(lambda self: self._t["qfrc_actuator"])
    cfrc_ext = property(lambda self: self._t["cfrc_ext"])
    ncon = property(lambda self: self._derived("ncon"))
    eq_active = property(lambda self: self._derived("eq_active"))
