"""The puppet character: the humanoid's body with an actuated root, for fast tests of task logic.

The puppet cannot fall over. Its pelvis rides on three slides (world x, y, z) and a yaw hinge,
all actuated, and gravity is compensated on its own bodies, so balance is not part of the
problem and a scripted oracle or a small PPO run on a CPU can walk it along a trajectory,
carry a box, climb and sit. Contacts still act on it (walls stop it, seats hold it up), and
its 32 hinges are PD-held exactly as the humanoid's.

Action space (37 values, each nominally in [-1, 1], clipped):

====== ====================================================================================
index  meaning
====== ====================================================================================
0-31   hinge PD targets, mapped as for the humanoid (`detach.envs.actions`)
32     forward velocity in the heading frame, `ROOT_LIN_SPEED` m/s per unit
33     lateral (leftward) velocity in the heading frame, `ROOT_LIN_SPEED` m/s per unit
34     yaw rate, `ROOT_YAW_RATE` rad/s per unit (counter-clockwise seen from above)
35     pelvis height target: `START_HEIGHT + ROOT_HEIGHT_SCALE * a` metres above z = 0,
       clipped to `ROOT_HEIGHT_RANGE`
36     grasp: > 0 asks to hold the nearest dynamic object (see `grasp_condition`)
====== ====================================================================================

Grasp rule: with the grasp action > 0, a dynamic object is attached to the pelvis by a weld
equality (keeping the relative pose it has at that instant) when both hands are within
`GRASP_HAND_DIST` metres of the object's bounding box (distance to the box surface in its
own frame; 0 inside). It stays attached while the grasp action stays > 0 and is released as
soon as it drops to <= 0. One object at a time.
"""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from detach.envs.humanoid import START_HEIGHT

ROOT_JOINTS: tuple[str, ...] = ("root_x", "root_y", "root_z", "root_yaw")
ROOT_ACTUATORS: tuple[str, ...] = ("root_vx", "root_vy", "root_z", "root_wz")
NUM_ACTIONS = 37
ROOT_LIN_SPEED = 2.0
ROOT_YAW_RATE = 3.0
ROOT_HEIGHT_SCALE = 1.6
ROOT_HEIGHT_RANGE = (0.05, 2.6)
GRASP_HAND_DIST = 0.12

_KV_LIN, _KV_YAW = 1500.0, 150.0
_KP_Z, _KV_Z = 6000.0, 1100.0


def add_root_joints(pelvis: mujoco.MjsBody) -> None:
    """Slides along world x, y, z and a yaw hinge on the pelvis; qpos = world x, y, z, yaw.

    The pelvis body sits at (0, 0, START_HEIGHT); `ref` makes each joint's value equal its
    world coordinate (displacement = qpos - ref).
    """
    for name, axis, ref in (("root_x", (1, 0, 0), 0.0), ("root_y", (0, 1, 0), 0.0),
                            ("root_z", (0, 0, 1), START_HEIGHT)):
        j = pelvis.add_joint(name=name)
        j.type = mujoco.mjtJoint.mjJNT_SLIDE
        j.axis = axis
        j.ref = ref
        j.armature = 0.1
    j = pelvis.add_joint(name="root_yaw")
    j.type = mujoco.mjtJoint.mjJNT_HINGE
    j.axis = (0, 0, 1)
    j.armature = 0.05


def add_root_actuators(spec: mujoco.MjSpec) -> None:
    """Velocity servos on x, y and yaw; a PD position servo on the pelvis height."""
    def servo(name: str, joint: str, kp: float, kv: float, crange, frange) -> None:
        a = spec.add_actuator(name=name, target=joint)
        a.trntype = mujoco.mjtTrn.mjTRN_JOINT
        a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
        a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
        a.gainprm[0] = kp if kp > 0 else kv
        a.biasprm[:3] = (0.0, -kp, -kv)
        a.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
        a.ctrlrange = crange
        a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
        a.forcerange = frange

    v = ROOT_LIN_SPEED
    servo("root_vx", "root_x", 0.0, _KV_LIN, (-v, v), (-3000.0, 3000.0))
    servo("root_vy", "root_y", 0.0, _KV_LIN, (-v, v), (-3000.0, 3000.0))
    servo("root_z", "root_z", _KP_Z, _KV_Z, ROOT_HEIGHT_RANGE, (-2500.0, 2500.0))
    servo("root_wz", "root_yaw", 0.0, _KV_YAW, (-ROOT_YAW_RATE, ROOT_YAW_RATE), (-600.0, 600.0))


def root_ctrl(actions: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Root actuator controls [N, 4] (world vx, world vy, height, yaw rate) from actions[:, 32:36].

    Velocities are commanded in the heading frame (forward, left) and rotated by the current
    yaw (radians) into the world frame, so that the action means the same at any heading.
    """
    a = actions.clamp(-1.0, 1.0)
    fwd, left = a[:, 32] * ROOT_LIN_SPEED, a[:, 33] * ROOT_LIN_SPEED
    c, s = torch.cos(yaw), torch.sin(yaw)
    vx, vy = c * fwd - s * left, s * fwd + c * left
    z = (START_HEIGHT + ROOT_HEIGHT_SCALE * a[:, 35]).clamp(*ROOT_HEIGHT_RANGE)
    wz = a[:, 34] * ROOT_YAW_RATE
    return torch.stack((vx, vy, z, wz), dim=-1)


def height_to_action(z: torch.Tensor | float) -> torch.Tensor | float:
    """Inverse of the height mapping: the action value that targets pelvis height z (m)."""
    return (z - START_HEIGHT) / ROOT_HEIGHT_SCALE


def point_box_distance(p: torch.Tensor, box_pos: torch.Tensor, box_quat: torch.Tensor,
                       half: torch.Tensor) -> torch.Tensor:
    """Distance (m) from points p [..., 3] to oriented boxes (centre, wxyz quat, half sizes).

    0 inside the box. Broadcasts over leading dimensions.
    """
    from detach.envs.torch_math import quat_rotate_inverse

    local = quat_rotate_inverse(box_quat, p - box_pos)
    excess = (local.abs() - half).clamp(min=0.0)
    return excess.norm(dim=-1)


def grasp_condition(hands: torch.Tensor, box_pos: torch.Tensor, box_quat: torch.Tensor,
                    half: torch.Tensor) -> torch.Tensor:
    """bool [N, K]: both hands within `GRASP_HAND_DIST` of dynamic object k.

    hands [N, 2, 3] world positions; box_pos [N, K, 3]; box_quat [N, K, 4] (wxyz);
    half [K, 3] half sizes.
    """
    d = point_box_distance(hands[:, :, None, :], box_pos[:, None], box_quat[:, None], half[None, None])
    return (d < GRASP_HAND_DIST).all(dim=1)


def default_root_qpos(pos2d: np.ndarray, yaw: np.ndarray, height: float = START_HEIGHT) -> np.ndarray:
    """Puppet root qpos [n, 4] (x, y, z, yaw) for start positions [n, 2] and yaws [n]."""
    n = len(yaw)
    return np.column_stack((pos2d[:, 0], pos2d[:, 1], np.full(n, height), yaw))
