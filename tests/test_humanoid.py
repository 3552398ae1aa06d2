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
    knee = m.joint("right_knee_x").range
    assert np.allclose(knee, np.deg2rad([-5.6, 5.6]))
    assert np.allclose(m.joint("left_knee_y").range, [0.0, np.deg2rad(160.0)])
    geom_types = set(int(t) for t in m.geom_type[1:])
    assert geom_types <= {int(mujoco.mjtGeom.mjGEOM_CAPSULE), int(mujoco.mjtGeom.mjGEOM_SPHERE),
                          int(mujoco.mjtGeom.mjGEOM_BOX)}
    assert m.opt.timestep == 1.0 / 120.0
    assert 40.0 < m.body_subtreemass[1] < 75.0


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
