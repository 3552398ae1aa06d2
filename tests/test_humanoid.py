"""The character model: counts and names, standing stability, puppet root actuation, backend."""

from __future__ import annotations

import mujoco
import numpy as np
import torch

from detach.character import body as H
from detach.character import build_character_model
from detach.character import puppet as P
from detach.sim.mujoco_batch import MujocoBatchBackend


def test_humanoid_counts_and_names():
    m = build_character_model("humanoid")
    bodies = [m.body(i).name for i in range(1, m.nbody)]
    assert bodies == list(H.BODY_NAMES) and len(bodies) == 15
    hinges = [m.joint(i).name for i in range(m.njnt) if m.jnt_type[i] == mujoco.mjtJoint.mjJNT_HINGE]
    assert hinges == list(H.DOF_NAMES) and len(hinges) == 32
    assert len(H.JOINT_GROUPS) == 12
    assert sum(len(g.axes) == 3 for g in H.JOINT_GROUPS) == 10  # abdomen, neck, shoulders, hips, knees, ankles
    assert [g.name for g in H.JOINT_GROUPS if len(g.axes) == 1] == ["right_elbow", "left_elbow"]
    assert m.nu == 32 and [m.actuator(i).name for i in range(m.nu)] == list(H.DOF_NAMES)
    geom_types = set(int(t) for t in m.geom_type[1:])
    assert geom_types <= {int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_SPHERE),
                          int(mujoco.mjtGeom.mjGEOM_BOX)}
    assert m.opt.timestep == 1.0 / 120.0
    assert 40.0 < m.body_subtreemass[1] < 75.0


# TokenHSI's phys_humanoid_v3.xml, written out by hand: hinge -> (range in degrees,
# stiffness, damping, motor gear, armature). Armature is the one value that differs (see
# `body.ARMATURE` for why).
TOKENHSI_HINGES = {
    "abdomen_x": ((-60, 60), 1000, 100, 200, .02), "abdomen_y": ((-60, 90), 1000, 100, 200, .02),
    "abdomen_z": ((-50, 50), 1000, 100, 200, .02),
    "neck_x": ((-50, 50), 100, 10, 50, .01), "neck_y": ((-40, 60), 100, 10, 50, .01),
    "neck_z": ((-45, 45), 100, 10, 50, .01),
    "right_shoulder_x": ((-180, 45), 400, 40, 100, .02), "right_shoulder_y": ((-180, 60), 400, 40, 100, .02),
    "right_shoulder_z": ((-90, 90), 400, 40, 100, .02), "right_elbow_y": ((-160, 0), 300, 30, 70, .01),
    "left_shoulder_x": ((-45, 180), 400, 40, 100, .02), "left_shoulder_y": ((-180, 60), 400, 40, 100, .02),
    "left_shoulder_z": ((-90, 90), 400, 40, 100, .02), "left_elbow_y": ((-160, 0), 300, 30, 70, .01),
    "right_hip_x": ((-60, 15), 500, 50, 200, .02), "right_hip_y": ((-140, 60), 500, 50, 200, .02),
    "right_hip_z": ((-60, 35), 500, 50, 200, .02),
    "right_knee_x": ((-5.625, 5.625), 500, 50, 150, .02), "right_knee_y": ((0, 160), 500, 50, 150, .02),
    "right_knee_z": ((-5.625, 5.625), 500, 50, 150, .02),
    "right_ankle_x": ((-30, 30), 400, 40, 90, .01), "right_ankle_y": ((-55, 55), 400, 40, 90, .01),
    "right_ankle_z": ((-40, 40), 400, 40, 90, .01),
    "left_hip_x": ((-15, 60), 500, 50, 200, .02), "left_hip_y": ((-140, 60), 500, 50, 200, .02),
    "left_hip_z": ((-35, 60), 500, 50, 200, .02),
    "left_knee_x": ((-5.625, 5.625), 500, 50, 150, .02), "left_knee_y": ((0, 160), 500, 50, 150, .02),
    "left_knee_z": ((-5.625, 5.625), 500, 50, 150, .02),
    "left_ankle_x": ((-30, 30), 400, 40, 90, .01), "left_ankle_y": ((-55, 55), 400, 40, 90, .01),
    "left_ankle_z": ((-40, 40), 400, 40, 90, .01),
}


def test_actuation_matches_tokenhsi_character():
    """Ranges, PD gains and torque limits of every hinge are TokenHSI's; armature is ours."""
    m = build_character_model("humanoid")
    assert sorted(TOKENHSI_HINGES) == sorted(H.DOF_NAMES)
    for name, ((lo, hi), kp, kd, gear, tokenhsi_armature) in TOKENHSI_HINGES.items():
        joint, act = m.joint(name), m.actuator(name)
        assert np.allclose(joint.range, np.deg2rad([lo, hi])), name
        assert np.allclose(act.ctrlrange, joint.range), name
        assert act.gainprm[0] == kp and np.allclose(act.biasprm[:3], [0.0, -kp, -kd]), name
        assert np.allclose(act.forcerange, [-gear, gear]), name
        assert m.dof_armature[joint.dofadr[0]] == H.ARMATURE > 2 * tokenhsi_armature, name


def test_humanoid_stands_on_default_pose():
    m = build_character_model("humanoid")
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    assert abs(d.xpos[1, 2] - H.START_HEIGHT) < 1e-9
    for _ in range(240):  # 2 s of zero PD targets = default pose
        mujoco.mj_step(m, d)
    assert abs(d.xpos[1, 2] - H.STAND_HEIGHT) < 0.02
    # adjacent bodies never collide (parent/child filtering)
    for c in d.contact[: d.ncon]:
        b1, b2 = m.geom_bodyid[c.geom1], m.geom_bodyid[c.geom2]
        assert m.body_parentid[b1] != b2 and m.body_parentid[b2] != b1


def test_puppet_root_follows_commands():
    m = build_character_model("puppet")
    assert m.nu == P.NUM_ACTIONS - 1  # grasp is not an actuator
    assert [m.joint(i).name for i in range(4)] == list(P.ROOT_JOINTS)
    be = MujocoBatchBackend(m, 2, nthread=1)
    act = torch.zeros(2, P.NUM_ACTIONS)
    act[:, 32] = 0.5  # 1 m/s forward
    act[1, 35] = 0.3 / P.ROOT_HEIGHT_SCALE  # raise the pelvis by 0.3 m
    yaw = torch.tensor([0.0, np.pi / 2])
    qpos = be.qpos.clone()
    qpos[:, 3] = yaw
    be.reset(torch.arange(2), qpos, torch.zeros_like(be.qvel))
    for _ in range(30):  # 1 s
        ctrl = torch.zeros(2, m.nu)
        ctrl[:, 32:36] = P.root_ctrl(act, be.qpos[:, 3])
        be.step(ctrl, 4)
    x, y, z = be.qpos[:, 0], be.qpos[:, 1], be.qpos[:, 2]
    assert abs(x[0] - 1.0) < 0.08 and abs(y[0]) < 0.01 and abs(z[0] - H.START_HEIGHT) < 0.01
    assert abs(y[1] - 1.0) < 0.08 and abs(x[1]) < 0.01 and abs(z[1] - H.START_HEIGHT - 0.3) < 0.02
    # joints held at the default pose by PD
    assert be.qpos[:, 4:].abs().max() < 0.02


def test_backend_matches_plain_mujoco():
    m = build_character_model("humanoid")
    be = MujocoBatchBackend(m, 3, nthread=2)
    rng = np.random.default_rng(0)
    ctrl = torch.as_tensor(rng.uniform(-0.3, 0.3, (3, m.nu)), dtype=torch.float32)
    for _ in range(5):
        be.step(ctrl, 4)
    d = mujoco.MjData(m)
    mujoco.mj_forward(m, d)
    d.ctrl[:] = ctrl[1].double().numpy()
    for _ in range(20):
        mujoco.mj_step(m, d)
    mujoco.mj_forward(m, d)
    np.testing.assert_allclose(be.xpos[1].double().numpy(), d.xpos, atol=1e-5)
    lin, ang = be.body_velocities()
    v = np.zeros(6)
    mujoco.mj_objectVelocity(m, d, mujoco.mjtObj.mjOBJ_XBODY, 5, v, 0)  # at the body origin
    np.testing.assert_allclose(lin[1, 5].double().numpy(), v[3:], atol=1e-4)
    np.testing.assert_allclose(ang[1, 5].double().numpy(), v[:3], atol=1e-4)
    # reset of a subset, in any order
    qpos = be.qpos[:2].clone()
    qpos[:, 0] = torch.tensor([5.0, 7.0])
    be.reset(torch.tensor([2, 0]), qpos, torch.zeros(2, m.nv))
    assert torch.allclose(be.xpos[[2, 0], 1, 0], torch.tensor([5.0, 7.0]))
    assert be.qvel[[0, 2]].abs().max() == 0
