"""The puppet: the humanoid's body with an actuated root, for fast CPU studies of task logic.

The puppet cannot fall over. Its pelvis rides on three slides (world x, y, z) and a yaw hinge,
all actuated, and gravity is compensated on its own bodies, so balance is not part of the
problem and a scripted oracle or a small PPO run on a CPU can walk it along a trajectory,
carry a box, climb and sit. Contacts still act on it (walls stop it, seats hold it up), and
its 32 hinges are PD-held exactly as the humanoid's.

Action space (37 values, each nominally in [-1, 1], clipped):

====== ====================================================================================
index  meaning
====== ====================================================================================
0-31   hinge PD targets, mapped as for the humanoid (`detach.character.actions`)
32     forward velocity in the heading frame, `ROOT_LIN_SPEED` m/s per unit
33     lateral (leftward) velocity in the heading frame, `ROOT_LIN_SPEED` m/s per unit
34     yaw rate, `ROOT_YAW_RATE` rad/s per unit (counter-clockwise seen from above)
35     pelvis height target: `START_HEIGHT + ROOT_HEIGHT_SCALE * a` metres above z = 0,
       clipped to `ROOT_HEIGHT_RANGE`
36     grasp: > 0 asks to hold the nearest dynamic object (see `grasp_condition`), below
       `RELEASE_BELOW` lets go
====== ====================================================================================

Grasp rule: with the grasp action > 0, a dynamic object is attached to the pelvis by a weld
equality (keeping the relative pose it has at that instant) when both hands are within
`GRASP_HAND_DIST` metres of the object's bounding box (distance to the box surface in its
own frame; 0 inside). It stays attached until the grasp action drops below `RELEASE_BELOW`
(-0.9; actions are clipped to [-1, 1]): the gap between taking hold (> 0) and letting go keeps
a grasp whose mean is above 0 from being dropped by exploration noise. With a release at 0, a
mean of 0.45 and std 0.3 let go at 7% of the steps; with a release at -0.5, the mean of about
0.1 that Carry training starts from let go at 2.3% (held boxes fell within 1.4 s on average);
at -0.9 it is 0.04%. Letting go is a deliberate action. One object at a time, and only during
a subtask whose skill holds objects (`Skill.holds_objects`: Carry); under any other skill the
env refuses the grasp and lets a held object go.
"""

from __future__ import annotations

import mujoco
import torch

from detach.character.actions import pd_actions, pd_targets
from detach.character.base import Character, ScriptedCommand, register_character
from detach.character.body import DOF_NAMES, NUM_DOF, START_HEIGHT
from detach.host_sync import may_any, rows_at
from detach.torch_math import point_box_distance, quat_conj, quat_mul, quat_rotate, rotate_yaw, wrap_angle

ROOT_JOINTS: tuple[str, ...] = ("root_x", "root_y", "root_z", "root_yaw")
ROOT_ACTUATORS: tuple[str, ...] = ("root_vx", "root_vy", "root_z", "root_wz")
NUM_ACTIONS = 37
GRASP_ACTION = NUM_ACTIONS - 1
HEIGHT_ACTION = 35
ROOT_LIN_SPEED = 2.0
ROOT_YAW_RATE = 3.0
ROOT_HEIGHT_SCALE = 1.6
ROOT_HEIGHT_RANGE = (0.05, 2.6)
GRASP_HAND_DIST = 0.12
RELEASE_BELOW = -0.9

_KV_LIN, _KV_YAW = 1500.0, 150.0
_KP_Z, _KV_Z = 6000.0, 1100.0


def root_ctrl(actions: torch.Tensor, yaw: torch.Tensor) -> torch.Tensor:
    """Root actuator controls [N, 4] (world vx, world vy, height, yaw rate) from actions[:, 32:36].

    Velocities are commanded in the heading frame (forward, left) and rotated by the current
    yaw (radians) into the world frame, so that the action means the same at any heading.
    """
    a = actions.clamp(-1.0, 1.0)
    fwd, left = a[:, 32] * ROOT_LIN_SPEED, a[:, 33] * ROOT_LIN_SPEED
    c, s = torch.cos(yaw), torch.sin(yaw)
    vx, vy = c * fwd - s * left, s * fwd + c * left
    z = (START_HEIGHT + ROOT_HEIGHT_SCALE * a[:, HEIGHT_ACTION]).clamp(*ROOT_HEIGHT_RANGE)
    wz = a[:, 34] * ROOT_YAW_RATE
    return torch.stack((vx, vy, z, wz), dim=-1)


def height_to_action(z: torch.Tensor | float) -> torch.Tensor | float:
    """Inverse of the height mapping: the action value that targets pelvis height z (m)."""
    return (z - START_HEIGHT) / ROOT_HEIGHT_SCALE


def grasp_condition(hands: torch.Tensor, box_pos: torch.Tensor, box_quat: torch.Tensor,
                    half: torch.Tensor) -> torch.Tensor:
    """bool [N, K]: both hands within `GRASP_HAND_DIST` of dynamic object k.

    hands [N, 2, 3] world positions; box_pos [N, K, 3]; box_quat [N, K, 4] (wxyz);
    half [K, 3] half sizes.
    """
    d = point_box_distance(hands[:, :, None, :], box_pos[:, None], box_quat[:, None], half[None, None])
    return (d < GRASP_HAND_DIST).all(dim=1)


@register_character
class Puppet(Character):
    name = "puppet"
    root_joint = ROOT_JOINTS[0]
    num_actions = NUM_ACTIONS
    action_std = 1.0
    """Its task rides on three root-velocity actions: it learns fastest with std 1 (0.5 and
    0.2 were slower, benchmarks/RESULTS.md)."""
    joint_power_weight = 0.0
    """Its hinges are cosmetic (balance is not its problem): the power penalty, a humanoid
    regulariser, would only teach it to freeze."""
    scriptable = True
    can_hold = True
    named_actions = {**{name: i for i, name in enumerate(DOF_NAMES)}, "grasp": GRASP_ACTION, "height": HEIGHT_ACTION}
    """Actions a task may never exercise, so a later stage may start them at a set mean
    (`train.init_action_mean`): the grasp holds nothing in Follow, a height target below the
    standing height is carried by the legs, and the hinges (named as in `DOF_NAMES`, in action
    units: the PD target's offset from 0 over half the joint's range) move nothing that Follow
    pays for, so Follow leaves all of them where PPO's noise drifted them. Where the hands are
    decides a grasp (both within `GRASP_HAND_DIST` of the box): Follow's arms reached Carry's
    boxes late, and with the torso and arms started at the oracle's reach pose a Follow cell
    grasped within 2 s from 94% of 48 evaluation starts instead of 4%, while a Follow cell whose
    own arms already reached the box lost with the same pose (results/laptop/NOTEBOOK.md)."""

    # ------------------------------------------------------------------ building
    def add_root(self, pelvis: mujoco.MjsBody) -> None:
        """Slides along world x, y, z and a yaw hinge; qpos = world x, y, z, yaw.

        The pelvis body sits at (0, 0, START_HEIGHT); `ref` makes each joint's value equal its
        world coordinate (displacement = qpos - ref).
        """
        for name, axis, ref in ((ROOT_JOINTS[0], (1, 0, 0), 0.0), (ROOT_JOINTS[1], (0, 1, 0), 0.0),
                                (ROOT_JOINTS[2], (0, 0, 1), START_HEIGHT)):
            j = pelvis.add_joint(name=name)
            j.type = mujoco.mjtJoint.mjJNT_SLIDE
            j.axis = axis
            j.ref = ref
            j.armature = 0.1
        j = pelvis.add_joint(name=ROOT_JOINTS[3])
        j.type = mujoco.mjtJoint.mjJNT_HINGE
        j.axis = (0, 0, 1)
        j.armature = 0.05

    def finish_body(self, spec: mujoco.MjSpec, bodies: dict[str, mujoco.MjsBody]) -> None:
        """Gravity compensation on its bodies; velocity servos on x, y and yaw, a PD position
        servo on the pelvis height (added after the 32 hinge actuators)."""
        for b in bodies.values():
            b.gravcomp = 1.0

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
        servo(ROOT_ACTUATORS[0], ROOT_JOINTS[0], 0.0, _KV_LIN, (-v, v), (-3000.0, 3000.0))
        servo(ROOT_ACTUATORS[1], ROOT_JOINTS[1], 0.0, _KV_LIN, (-v, v), (-3000.0, 3000.0))
        servo(ROOT_ACTUATORS[2], ROOT_JOINTS[2], _KP_Z, _KV_Z, ROOT_HEIGHT_RANGE, (-2500.0, 2500.0))
        servo(ROOT_ACTUATORS[3], ROOT_JOINTS[3], 0.0, _KV_YAW, (-ROOT_YAW_RATE, ROOT_YAW_RATE), (-600.0, 600.0))

    def link_objects(self, spec: mujoco.MjSpec, object_bodies: dict[int, str]) -> dict[int, str]:
        """An inactive weld pelvis -> object per movable object, switched on to grasp."""
        names = {}
        for index, body in object_bodies.items():
            e = spec.add_equality(name=f"grasp_obj{index}", type=mujoco.mjtEq.mjEQ_WELD,
                                  name1="pelvis", name2=body)
            e.objtype = mujoco.mjtObj.mjOBJ_BODY
            e.active = False
            e.data[:] = 0.0
            e.data[6] = 1.0   # identity relative rotation until the env sets the real pose
            e.data[10] = 1.0  # torquescale
            e.solref = (0.02, 1.0)
            names[index] = e.name
        return names

    # ------------------------------------------------------------------ run time
    def bind(self, num_envs, device, backend, movable, hand_ids, root_qpos_adr) -> None:
        super().bind(num_envs, device, backend, movable, hand_ids, root_qpos_adr)
        self.grasp_obj = torch.full((num_envs,), -1, dtype=torch.long, device=device)
        self.movable_half = torch.tensor([list(m.half_size) for m in movable], dtype=torch.float32,
                                         device=device).reshape(-1, 3)
        self.movable_index = torch.tensor([m.index for m in movable], dtype=torch.long, device=device)

    def reset(self, ids: torch.Tensor) -> None:
        self.grasp_obj.index_fill_(0, ids, -1)  # `[ids] = -1` would copy the -1 to the device

    def held_object(self) -> torch.Tensor:
        return self.grasp_obj

    def pre_step(self, actions: torch.Tensor, state, may_hold: torch.Tensor) -> None:
        """The grasp rule (module docstring): weld on request when both hands are near, only
        where `may_hold`; elsewhere a held object is let go. Masks throughout: no host read
        where that is not free (`detach.host_sync`)."""
        if not self.movable:
            return
        g = actions[:, GRASP_ACTION]
        release = (self.grasp_obj >= 0) & ((g < RELEASE_BELOW) | ~may_hold)
        if may_any(release):
            off = torch.zeros(self.num_envs, device=self.device)
            for k, obj in enumerate(self.movable):
                self.backend.set_equality(release & (self.grasp_obj == k), obj.link_eq, off)
            self.grasp_obj.masked_fill_(release, -1)
        cand = (g > 0.0) & (self.grasp_obj < 0) & may_hold
        if not may_any(cand):
            return
        dpos, dquat = state.obj_pos[:, self.movable_index], state.obj_quat[:, self.movable_index]
        ok = grasp_condition(state.body_pos[:, self.hand_ids], dpos, dquat, self.movable_half) & cand[:, None]
        first = torch.where(ok.any(-1), ok.float().argmax(-1), torch.full_like(self.grasp_obj, -1))
        for k in range(len(self.movable)):
            sel = first == k
            if may_any(sel):
                self._weld(sel, k, state.root_pos, state.root_quat, dpos[:, k], dquat[:, k])

    def hold(self, ids, slots, root_pos, root_quat, obj_pos, obj_quat) -> None:
        slot = rows_at(self.num_envs, ids, slots, -1)
        rows = [rows_at(self.num_envs, ids, t) for t in (root_pos, root_quat, obj_pos, obj_quat)]
        for k in range(len(self.movable)):
            sel = slot == k
            if may_any(sel):
                self._weld(sel, k, *rows)

    def _weld(self, mask: torch.Tensor, k: int, root_pos: torch.Tensor, root_quat: torch.Tensor,
              obj_pos: torch.Tensor, obj_quat: torch.Tensor) -> None:
        """Attach movable object k to the pelvis of the envs in mask [N], keeping their relative
        pose (root_pos, root_quat, obj_pos, obj_quat: [N, ...], world frame)."""
        inv = quat_conj(root_quat)
        data = torch.zeros(len(mask), 12, device=self.device)
        data[:, 3:6], data[:, 6:10], data[:, 10] = quat_rotate(inv, obj_pos - root_pos), quat_mul(inv, obj_quat), 1.0
        self.backend.set_equality(mask, self.movable[k].link_eq, torch.ones(len(mask), device=self.device), data)
        self.grasp_obj.masked_fill_(mask, k)

    def controls(self, actions: torch.Tensor, qpos: torch.Tensor) -> torch.Tensor:
        yaw = qpos[:, self.root_qpos_adr + 3]
        return torch.cat((pd_targets(actions, self.dof_lo, self.dof_hi), root_ctrl(actions, yaw)), dim=-1)

    def write_root(self, qpos, qvel, q_adr, v_adr, xy, height, yaw, tilt, lin, ang) -> None:
        qpos[:, q_adr:q_adr + 4] = torch.stack((xy[:, 0], xy[:, 1], height, yaw), dim=-1)
        w = rotate_yaw(yaw, lin)
        qvel[:, v_adr:v_adr + 4] = torch.stack((w[:, 0], w[:, 1], w[:, 2], ang[:, 2]), dim=-1)

    def scripted_actions(self, cmd: ScriptedCommand) -> torch.Tensor:
        a = torch.zeros(len(cmd.yaw), NUM_ACTIONS, device=cmd.yaw.device)
        a[:, :NUM_DOF] = pd_actions(cmd.hinges, self.dof_lo, self.dof_hi)
        c, s = torch.cos(cmd.yaw), torch.sin(cmd.yaw)
        v = cmd.velocity
        a[:, 32] = (c * v[:, 0] + s * v[:, 1]) / ROOT_LIN_SPEED
        a[:, 33] = (-s * v[:, 0] + c * v[:, 1]) / ROOT_LIN_SPEED
        a[:, 34] = (5.0 * wrap_angle(cmd.yaw_target - cmd.yaw)).clamp(-ROOT_YAW_RATE, ROOT_YAW_RATE) / ROOT_YAW_RATE
        a[:, HEIGHT_ACTION] = height_to_action(cmd.height)
        a[:, GRASP_ACTION] = cmd.grasp
        return a.clamp(-1.0, 1.0)
