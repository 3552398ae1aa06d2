"""The balance assist: a righting torque on the pelvis, a training aid (`train.balance_assist`).

Hand-written because it is three lines of rigid-body arithmetic no library offers as such: the
torque turns the pelvis's up axis back to the world's (about the horizontal axis between
them, in proportion to the tilt angle) and damps the roll and pitch rates; yaw is never
touched, so the policy still steers.
"""

from __future__ import annotations

import torch

from detach.sim import PhysicsBackend
from detach.sim.state import SimState
from detach.torch_math import quat_rotate

MAX_TILT = 0.6
"""rad: the torque stops growing here. A body tilted further has fallen, and the full gain at
a humanoid upside down (3 kN m on a 10 kg pelvis) made the simulation diverge (bad QACC)."""
MAX_SPIN = 10.0
"""rad/s: the roll/pitch rate the damping acts on is capped at this, for the same reason."""


def righting_wrench(root_quat: torch.Tensor, root_ang: torch.Tensor, torque: float, damping: float) -> torch.Tensor:
    """[N, 6] world-frame wrench (zero force, then torque) on the pelvis from its orientation
    root_quat [N, 4] (wxyz) and angular velocity root_ang [N, 3] (world frame)."""
    up = quat_rotate(root_quat, root_quat.new_tensor((0.0, 0.0, 1.0)).expand_as(root_ang))
    axis = torch.cross(up, up.new_tensor((0.0, 0.0, 1.0)).expand_as(up), dim=-1)  # |axis| = sin(tilt)
    sin = axis.norm(dim=-1, keepdim=True)
    tilt = torch.atan2(sin, up[:, 2:3]).clamp(max=MAX_TILT)
    spin = root_ang.clone()
    spin[:, 2] = 0.0
    spin = spin * (MAX_SPIN / spin.norm(dim=-1, keepdim=True).clamp_min(MAX_SPIN))
    tau = torque * axis * (tilt / sin.clamp_min(1e-6)) - damping * spin
    return torch.cat((torch.zeros_like(tau), tau), dim=-1)


class BalanceAssist:
    """The assist of one env's world: off until `set` gives it gains; `apply` before each
    control step writes the wrench for the state just read (held through the substeps)."""

    def __init__(self, backend: PhysicsBackend, pelvis_body: int) -> None:
        self.backend, self.pelvis_body = backend, pelvis_body
        self.gains: tuple[float, float] | None = None
        """(torque, damping) while the assist is on or its zero wrench is still to be written."""

    def set(self, torque: float, damping: float) -> None:
        """Righting torque (N m/rad of tilt) and roll/pitch damping (N m s/rad) from the next
        step on; 0, 0 removes it. A training aid: `train.balance_assist` sets it each
        iteration, nothing else does."""
        if torque > 0.0 or damping > 0.0 or self.gains is not None:
            self.gains = (float(torque), float(damping))

    def apply(self, state: SimState) -> None:
        if self.gains is None:
            return
        torque, damping = self.gains
        self.backend.set_body_wrench(self.pelvis_body, righting_wrench(state.root_quat, state.body_ang[:, 0],
                                                                       torque, damping))
        if torque == 0.0 and damping == 0.0:
            self.gains = None  # the zero wrench is written once, then nothing
