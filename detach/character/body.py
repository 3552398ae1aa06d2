"""The project's 15-body, 32-DoF character body, built with `mujoco.MjSpec` (no XML to keep in sync).

Proportions follow the AMP/TokenHSI character: 15 rigid bodies, 12 controllable joints with
32 hinge degrees of freedom (3-DoF abdomen, neck, shoulders, hips, knees and ankles as three
hinges x/y/z each; 1-DoF elbows). Knees are 3-DoF like TokenHSI's (x/z limited to +-5.625 deg,
y 0..160 deg). Frames: the character faces +X, +Y is its left, +Z is up; at the default pose
(all hinges 0) it stands upright with its arms hanging down and the pelvis origin
`START_HEIGHT` above the floor.

Every hinge is driven by a PD position actuator (MuJoCo `general` actuator with an affine
bias: force = kp * (target - q) - kd * qdot, clipped to a force limit) evaluated at every
physics step, while the policy sets the targets at the control rate (30 Hz). With the
`implicitfast` integrator the damping term is integrated implicitly, which keeps the stiff
gains stable at dt = 1/120 s.

Every character (`detach.character`) shares this body and differs only in its root: how the
pelvis is attached to the world and what actuates it.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable

import mujoco
import numpy as np

START_HEIGHT = 0.94
"""Pelvis height in metres at which episodes start (feet ~5 mm above the floor)."""

STAND_HEIGHT = 0.935
"""Pelvis height in metres of the default pose standing on flat ground (sole at z = 0)."""

FLOOR_TO_SOLE = 0.935
"""Distance from the pelvis origin to the sole at the default pose, metres."""

CHARACTER_GEOM_GROUP = 1
"""Geom group of the character's geoms (rays for height maps exclude it)."""


@dataclass(frozen=True)
class JointGroup:
    """One controllable joint: a 1-DoF hinge or three hinges about local x, y, z."""

    name: str
    body: str
    axes: str
    """Subset of "xyz": the hinge axes, in the body frame."""
    ranges: tuple[tuple[float, float], ...]
    """Range in radians of each hinge, in the order of `axes`."""
    kp: float
    kd: float
    max_force: float
    """Actuator force limit, N m."""


def _deg(*ranges: tuple[float, float]) -> tuple[tuple[float, float], ...]:
    return tuple((float(np.deg2rad(lo)), float(np.deg2rad(hi))) for lo, hi in ranges)


_KNEE = _deg((-5.625, 5.625), (0.0, 160.0), (-5.625, 5.625))

JOINT_GROUPS: tuple[JointGroup, ...] = (
    JointGroup("abdomen", "torso", "xyz", _deg((-60, 60), (-60, 90), (-50, 50)), 1000, 100, 200),
    JointGroup("neck", "head", "xyz", _deg((-50, 50), (-40, 60), (-45, 45)), 100, 10, 50),
    JointGroup("right_shoulder", "right_upper_arm", "xyz",
               _deg((-180, 45), (-180, 60), (-90, 90)), 400, 40, 100),
    JointGroup("right_elbow", "right_lower_arm", "y", _deg((-160, 0)), 300, 30, 70),
    JointGroup("left_shoulder", "left_upper_arm", "xyz",
               _deg((-45, 180), (-180, 60), (-90, 90)), 400, 40, 100),
    JointGroup("left_elbow", "left_lower_arm", "y", _deg((-160, 0)), 300, 30, 70),
    JointGroup("right_hip", "right_thigh", "xyz", _deg((-60, 15), (-140, 60), (-60, 35)), 500, 50, 200),
    JointGroup("right_knee", "right_shin", "xyz", _KNEE, 500, 50, 150),
    JointGroup("right_ankle", "right_foot", "xyz", _deg((-30, 30), (-55, 55), (-40, 40)), 400, 40, 90),
    JointGroup("left_hip", "left_thigh", "xyz", _deg((-15, 60), (-140, 60), (-35, 60)), 500, 50, 200),
    JointGroup("left_knee", "left_shin", "xyz", _KNEE, 500, 50, 150),
    JointGroup("left_ankle", "left_foot", "xyz", _deg((-30, 30), (-55, 55), (-40, 40)), 400, 40, 90),
)
"""The 12 controllable joints (32 hinges) in actuator/DoF order.

Ranges, PD gains (kp = the joint's `stiffness`, kd = its `damping`) and torque limits (the
motor `gear`, which IsaacGym uses as the drive's effort limit) are those of TokenHSI's
character, `phys_humanoid_v3.xml` in liangpan99/TokenHSI, so that a policy meets the same
actuation limits as in the paper; `tests/test_humanoid.py` compares them hinge by hinge.
Armature is the one value we keep our own (`ARMATURE`)."""

ARMATURE = 0.08
"""Rotor inertia added to every hinge, kg m^2. TokenHSI uses 0.01-0.02, which PhysX's
implicit joint drives tolerate; in MuJoCo (`implicitfast`, dt = 1/120 s) with these gains the
humanoid diverged (bad QACC) within 3 s on 6 of 6 seeds of full-range random PD targets,
0.04 held, and 0.08 gives twice that margin."""

BODY_NAMES: tuple[str, ...] = (
    "pelvis", "torso", "head",
    "right_upper_arm", "right_lower_arm", "right_hand",
    "left_upper_arm", "left_lower_arm", "left_hand",
    "right_thigh", "right_shin", "right_foot",
    "left_thigh", "left_shin", "left_foot",
)
"""The 15 rigid bodies in kinematic-tree (MuJoCo body id) order; index 0 is the root."""

KEY_BODIES: tuple[str, ...] = ("right_hand", "left_hand", "right_foot", "left_foot")
"""Bodies whose positions enter the AMP observation."""

HANDS: tuple[str, ...] = ("right_hand", "left_hand")

DOF_NAMES: tuple[str, ...] = tuple(f"{g.name}_{a}" for g in JOINT_GROUPS for a in g.axes)
"""Names of the 32 hinges (MuJoCo joint names), e.g. `right_knee_y`."""

NUM_DOF = len(DOF_NAMES)


def dof_ranges() -> np.ndarray:
    """[32, 2] hinge ranges in radians, DoF order."""
    return np.array([r for g in JOINT_GROUPS for r in g.ranges], dtype=np.float64)


# --- geometry ----------------------------------------------------------------------------
# Each body: (name, parent, position in the parent frame, geoms). A geom is
# (type, size, fromto or pos); sizes in metres. Values are our own, sized so that leg
# length (pelvis origin to sole) is 0.935 m and the standing height is about 1.62 m.

_CAP, _SPH, _BOX = mujoco.mjtGeom.mjGEOM_CAPSULE, mujoco.mjtGeom.mjGEOM_SPHERE, mujoco.mjtGeom.mjGEOM_BOX

_BODIES: tuple[tuple[str, str, tuple[float, float, float], tuple], ...] = (
    ("torso", "pelvis", (0.0, 0.0, 0.12),
     ((_CAP, (0.11,), ((0.0, 0.0, 0.03), (0.0, 0.0, 0.17))),
      (_CAP, (0.08,), ((-0.01, -0.09, 0.24), (-0.01, 0.09, 0.24))))),
    ("head", "torso", (0.0, 0.0, 0.34), ((_SPH, (0.095,), (0.0, 0.0, 0.13)),)),
    ("right_upper_arm", "torso", (-0.01, -0.2, 0.25),
     ((_CAP, (0.045,), ((0.0, 0.0, -0.04), (0.0, 0.0, -0.24))),)),
    ("right_lower_arm", "right_upper_arm", (0.0, 0.0, -0.28),
     ((_CAP, (0.04,), ((0.0, 0.0, -0.03), (0.0, 0.0, -0.2))),)),
    ("right_hand", "right_lower_arm", (0.0, 0.0, -0.25), ((_SPH, (0.04,), (0.0, 0.0, 0.0)),)),
    ("left_upper_arm", "torso", (-0.01, 0.2, 0.25),
     ((_CAP, (0.045,), ((0.0, 0.0, -0.04), (0.0, 0.0, -0.24))),)),
    ("left_lower_arm", "left_upper_arm", (0.0, 0.0, -0.28),
     ((_CAP, (0.04,), ((0.0, 0.0, -0.03), (0.0, 0.0, -0.2))),)),
    ("left_hand", "left_lower_arm", (0.0, 0.0, -0.25), ((_SPH, (0.04,), (0.0, 0.0, 0.0)),)),
    ("right_thigh", "pelvis", (0.0, -0.09, -0.03),
     ((_CAP, (0.06,), ((0.0, 0.0, -0.05), (0.0, 0.0, -0.37))),)),
    ("right_shin", "right_thigh", (0.0, 0.0, -0.42),
     ((_CAP, (0.05,), ((0.0, 0.0, -0.04), (0.0, 0.0, -0.35))),)),
    ("right_foot", "right_shin", (0.0, 0.0, -0.41), ((_BOX, (0.1, 0.045, 0.0325), (0.045, 0.0, -0.0425)),)),
    ("left_thigh", "pelvis", (0.0, 0.09, -0.03),
     ((_CAP, (0.06,), ((0.0, 0.0, -0.05), (0.0, 0.0, -0.37))),)),
    ("left_shin", "left_thigh", (0.0, 0.0, -0.42),
     ((_CAP, (0.05,), ((0.0, 0.0, -0.04), (0.0, 0.0, -0.35))),)),
    ("left_foot", "left_shin", (0.0, 0.0, -0.41), ((_BOX, (0.1, 0.045, 0.0325), (0.045, 0.0, -0.0425)),)),
)


def _foot_to_sole() -> float:
    """Height (m) of a foot body's origin above its sole: the bottom of its box geom."""
    (_gtype, size, pos), = dict((b[0], b[3]) for b in _BODIES)["right_foot"]
    return -(pos[2] - size[2])


FOOT_TO_SOLE = _foot_to_sole()
"""Height of a foot body's origin above its sole, metres (0.075)."""
FEET: tuple[str, ...] = ("right_foot", "left_foot")

_PELVIS_GEOMS = ((_CAP, (0.09,), ((0.0, -0.07, 0.0), (0.0, 0.07, 0.0))),)
_AXES = {"x": (1.0, 0.0, 0.0), "y": (0.0, 1.0, 0.0), "z": (0.0, 0.0, 1.0)}


def _add_geoms(body: mujoco.MjsBody, geoms: tuple, friction: float) -> None:
    for gtype, size, where in geoms:
        g = body.add_geom()
        g.type = gtype
        g.size[: len(size)] = size
        if gtype == _CAP:
            g.fromto = np.concatenate(where)
        else:
            g.pos = where
        g.friction = (friction, 0.005, 0.0001)
        g.group = CHARACTER_GEOM_GROUP
        g.rgba = (0.75, 0.6, 0.45, 1.0)
        g.density = 985.0  # human tissue, kg/m^3


def add_body(parent: mujoco.MjsBody, spec: mujoco.MjSpec, add_root: Callable[[mujoco.MjsBody], None],
             friction: float = 1.0) -> dict[str, mujoco.MjsBody]:
    """Add the 15 bodies, 32 hinges and their PD actuators under `parent`; returns the bodies.

    `add_root(pelvis)` adds the character's root joint(s) to the pelvis before anything else,
    so that the root comes first in qpos. Actuators are added to `spec` in `DOF_NAMES` order:
    `ctrl[:32]` are always the hinge PD targets, whatever a character adds after them.
    """
    pelvis = parent.add_body(name="pelvis", pos=(0.0, 0.0, START_HEIGHT))
    add_root(pelvis)
    _add_geoms(pelvis, _PELVIS_GEOMS, friction)
    # An accelerometer makes MuJoCo run mj_rnePostConstraint, which fills cfrc_ext (contact
    # forces per body) for the backend's contact view; it costs O(nbody).
    pelvis.add_site(name="imu")
    spec.add_sensor(name="pelvis_acc", type=mujoco.mjtSensor.mjSENS_ACCELEROMETER,
                    objtype=mujoco.mjtObj.mjOBJ_SITE, objname="imu")
    bodies = {"pelvis": pelvis}
    for name, par, pos, geoms in _BODIES:
        b = bodies[par].add_body(name=name, pos=pos)
        bodies[name] = b
        _add_geoms(b, geoms, friction)
    for g in JOINT_GROUPS:
        for axis, rng in zip(g.axes, g.ranges):
            j = bodies[g.body].add_joint(name=f"{g.name}_{axis}")
            j.type = mujoco.mjtJoint.mjJNT_HINGE
            j.axis = _AXES[axis]
            j.range = rng
            j.limited = mujoco.mjtLimited.mjLIMITED_TRUE
            j.armature = ARMATURE
    for g in JOINT_GROUPS:
        for axis, rng in zip(g.axes, g.ranges):
            a = spec.add_actuator(name=f"{g.name}_{axis}", target=f"{g.name}_{axis}")
            a.trntype = mujoco.mjtTrn.mjTRN_JOINT
            a.gaintype = mujoco.mjtGain.mjGAIN_FIXED
            a.biastype = mujoco.mjtBias.mjBIAS_AFFINE
            a.gainprm[0] = g.kp
            a.biasprm[:3] = (0.0, -g.kp, -g.kd)
            a.ctrllimited = mujoco.mjtLimited.mjLIMITED_TRUE
            a.ctrlrange = rng
            a.forcelimited = mujoco.mjtLimited.mjLIMITED_TRUE
            a.forcerange = (-g.max_force, g.max_force)
    return bodies


def configure_options(spec: mujoco.MjSpec, physics_dt: float, iterations: int) -> None:
    """Simulation options shared by every model of the project (units: seconds)."""
    spec.option.timestep = physics_dt
    spec.option.integrator = mujoco.mjtIntegrator.mjINT_IMPLICITFAST
    spec.option.iterations = max(int(iterations), 1)
    spec.option.ls_iterations = 8
    spec.compiler.autolimits = True
    spec.compiler.degree = False  # every angle in this project is in radians


def add_floor(spec: mujoco.MjSpec, friction: float = 1.0, size: float = 0.0) -> mujoco.MjsGeom:
    """An infinite floor plane at z = 0 (size 0 = infinite), plus a light."""
    g = spec.worldbody.add_geom(name="floor")
    g.type = mujoco.mjtGeom.mjGEOM_PLANE
    g.size = (size, size, 0.05)
    g.friction = (friction, 0.005, 0.0001)
    g.rgba = (0.55, 0.6, 0.65, 1.0)
    g.group = 0
    spec.worldbody.add_light(pos=(0.0, 0.0, 6.0), dir=(0.0, 0.0, -1.0), type=mujoco.mjtLightType.mjLIGHT_DIRECTIONAL)
    return g
