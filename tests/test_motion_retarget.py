"""BVH import and retargeting (through the CLI), rotation conventions, CLI error handling."""

from __future__ import annotations

from pathlib import Path

import mujoco
import numpy as np
import pytest

from detach.character.body import BODY_NAMES, DOF_NAMES
from detach.motion.bvh_import import read_bvh
from detach.motion.cli import main
from detach.motion.clip import load_clip
from detach.motion.builtin import builtin_clips
from detach.motion.kinematics import humanoid_fk
from detach.motion.retarget import load_map, retarget
from detach.motion.rotations import (euler_xyz_from_matrix, matrix_from_euler_xyz, matrix_to_quat,
                                     quat_from_axis_angle, quat_mul, quat_rotate, quat_to_matrix)

DATA = Path(__file__).parent / "data"
KNEE_BVH = DATA / "cmu_knee.bvh"  # 3 frames: LeftLeg bends 0, 45, 90 deg about BVH +X; arms lowered


def test_hinges_nest_as_euler_xyz():
    fk = humanoid_fk()
    a, b, c = 0.3, -0.5, 0.7
    dof = np.zeros(len(DOF_NAMES))
    for axis, v in zip("xyz", (a, b, c)):
        dof[DOF_NAMES.index(f"left_hip_{axis}")] = v
    fk.set_pose(np.zeros(3), np.array([1.0, 0, 0, 0]), dof)
    xmat = fk.data.xmat[fk.model.body("left_thigh").id].reshape(3, 3)
    np.testing.assert_allclose(xmat, matrix_from_euler_xyz(a, b, c), atol=1e-12)
    np.testing.assert_allclose(euler_xyz_from_matrix(xmat), [a, b, c], atol=1e-9)
    q = matrix_to_quat(xmat)
    np.testing.assert_allclose(quat_to_matrix(q), xmat, atol=1e-12)
    quat = np.zeros(4)
    mujoco.mju_mat2Quat(quat, xmat.reshape(-1))
    np.testing.assert_allclose(q, quat * np.sign(quat[0]), atol=1e-12)


def test_cli_import_knee(tmp_path, capsys):
    assert main(["import", str(KNEE_BVH), "--map", "cmu", "--skill", "walk", "--out", str(tmp_path)]) == 0
    line = capsys.readouterr().out.strip()
    assert line.startswith("wrote ") and "cmu_knee" in line and "\n" not in line
    clip = load_clip(tmp_path / "cmu_knee.npz")
    assert clip.num_frames == 3 and clip.fps == 30.0 and clip.skill == "walk"
    knee = DOF_NAMES.index("left_knee_y")
    np.testing.assert_allclose(clip.dof_pos[:, knee], [0.0, np.pi / 4, np.pi / 2], atol=1e-4)
    others = np.delete(clip.dof_pos, knee, axis=1)
    np.testing.assert_allclose(others, 0.0, atol=1e-4)
    # root: hips at BVH z = 0, 1, 2 units -> our x = 0, 0.056, 0.112 m; soles on the floor
    np.testing.assert_allclose(clip.root_pos[:, 0], [0.0, 0.056, 0.112], atol=1e-6)
    np.testing.assert_allclose(clip.root_pos[:, 2], 0.935, atol=1e-3)
    feet = humanoid_fk().run(clip.root_pos, clip.root_quat, clip.dof_pos).foot_bottom
    assert feet.min() == pytest.approx(0.0, abs=1e-6)
    # --scale and --fps
    assert main(["import", str(KNEE_BVH), "--out", str(tmp_path), "--scale", "0.1", "--fps", "60",
                 "--name", "k60", "--skill", "sit"]) == 0
    k60 = load_clip(tmp_path / "k60.npz")
    assert k60.num_frames == 5 and k60.skill == "sit"
    np.testing.assert_allclose(k60.root_pos[-1, 0], 0.2, atol=1e-6)
    np.testing.assert_allclose(k60.dof_pos[:, knee], np.linspace(0, np.pi / 2, 5), atol=1e-4)


def test_t_pose_arms_keep_their_rest_difference(tmp_path):
    """Without the arm-lowering rotations the BVH arms stay in a T-pose: shoulders at +-90 deg."""
    text = KNEE_BVH.read_text().splitlines()
    start = text.index("Frame Time: 0.0333333") + 1
    for k in range(start, len(text)):
        vals = text[k].split()
        vals[57] = vals[69] = "0"
        text[k] = " ".join(vals)
    tpose = tmp_path / "tpose.bvh"
    tpose.write_text("\n".join(text) + "\n")
    clip, clipped = retarget(read_bvh(tpose), load_map("cmu"))
    assert clipped == 0.0
    np.testing.assert_allclose(clip.dof_pos[0, DOF_NAMES.index("left_shoulder_x")], np.pi / 2, atol=1e-4)
    np.testing.assert_allclose(clip.dof_pos[0, DOF_NAMES.index("right_shoulder_x")], -np.pi / 2, atol=1e-4)
    hand = clip.body_pos[0, BODY_NAMES.index("left_hand")] - clip.body_pos[0, BODY_NAMES.index("left_upper_arm")]
    np.testing.assert_allclose(hand / np.linalg.norm(hand), [0, 1, 0], atol=1e-6)  # arm straight out left


def test_random_poses_keep_bone_directions():
    """Random rotations of hips, spine, arms, root and the knee: our bones point where theirs do."""
    rng = np.random.default_rng(0)
    bvh = read_bvh(KNEE_BVH)
    f = 40
    q = np.tile(bvh.local_quat[:1], (f, 1, 1))
    # up to 0.5 rad, 0.25 at the hips (whose inward range stops at 15 degrees)
    for j, most in (("LeftUpLeg", 0.25), ("RightUpLeg", 0.25), ("Spine", 0.5), ("LeftArm", 0.5),
                    ("RightArm", 0.5), ("Hips", 0.5)):
        ax = rng.normal(size=(f, 3))
        ax /= np.linalg.norm(ax, axis=1, keepdims=True)
        q[:, bvh.index(j)] = quat_mul(q[:, bvh.index(j)], quat_from_axis_angle(ax, rng.uniform(0, most, f)))
    q[:, bvh.index("LeftLeg")] = quat_from_axis_angle(np.array([1.0, 0, 0]), rng.uniform(0, 2.0, f))
    bvh.local_quat, bvh.root_pos = q, np.tile(bvh.root_pos[:1], (f, 1))
    jmap = load_map("cmu")
    clip, clipped = retarget(bvh, jmap)
    assert clipped == 0.0
    g = bvh.global_quat()
    pos = np.zeros((f, len(bvh.names), 3))
    for j, p in enumerate(bvh.parents):
        if p >= 0:
            pos[:, j] = pos[:, p] + quat_rotate(g[:, p], np.broadcast_to(bvh.offsets[j], (f, 3)))
    pos = pos @ jmap.axes.T
    b = {n: i for i, n in enumerate(BODY_NAMES)}
    unit = lambda v: v / np.linalg.norm(v, axis=-1, keepdims=True)  # noqa: E731
    for (o0, o1), (t0, t1) in ((("left_thigh", "left_shin"), ("LeftUpLeg", "LeftLeg")),
                               (("left_shin", "left_foot"), ("LeftLeg", "LeftFoot")),
                               (("right_thigh", "right_shin"), ("RightUpLeg", "RightLeg")),
                               (("left_upper_arm", "left_lower_arm"), ("LeftArm", "LeftForeArm")),
                               (("right_lower_arm", "right_hand"), ("RightForeArm", "RightHand")),
                               (("torso", "head"), ("Spine1", "Neck"))):
        ours = unit(clip.body_pos[:, b[o1]] - clip.body_pos[:, b[o0]])
        theirs = unit(pos[:, bvh.index(t1)] - pos[:, bvh.index(t0)])
        np.testing.assert_allclose(ours, theirs, atol=1e-5, err_msg=o0)


def _err(capsys) -> str:
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1, captured.err
    return lines[0]


def test_cli_errors(tmp_path, capsys):
    assert main(["import", str(tmp_path / "missing.bvh")]) == 2
    assert "missing.bvh: no such file" in _err(capsys)
    junk = tmp_path / "junk.bvh"
    junk.write_text("this is not a bvh\n")
    assert main(["import", str(junk)]) == 2
    assert "junk.bvh: not a BVH file" in _err(capsys)
    renamed = tmp_path / "renamed.bvh"
    renamed.write_text(KNEE_BVH.read_text().replace("LeftForeArm", "LeftElbow"))
    assert main(["import", str(renamed), "--map", "cmu"]) == 2
    line = _err(capsys)  # every missing joint in one line, and where the map format is documented
    assert "renamed.bvh: map 'cmu' needs 1 joint(s) the file does not have: " \
           "LeftForeArm (left_shoulder aim, left_elbow)" in line and "docs/MOCAP.md" in line
    assert main(["import", str(KNEE_BVH), "--map", "nosuchmap"]) == 2
    assert "nosuchmap: unknown joint map" in _err(capsys)
    truncated = tmp_path / "truncated.bvh"
    truncated.write_text("\n".join(KNEE_BVH.read_text().splitlines()[:-1]) + "\n")
    assert main(["import", str(truncated)]) == 2  # bvhio alone would loop forever on this file
    assert "truncated.bvh: Frames: 3 but only 2 frame lines" in _err(capsys)
    assert main(["import", str(KNEE_BVH), "--skill", "dance", "--out", str(tmp_path)]) == 2
    assert "unknown skill label 'dance'" in _err(capsys)
    assert main(["list", str(tmp_path / "nodir")]) == 2
    assert "nodir: no such folder" in _err(capsys)


def test_cli_list_and_builtin(tmp_path, capsys):
    assert main(["builtin", "--out", str(tmp_path)]) == 0
    assert len(list(tmp_path.glob("*.npz"))) == len(builtin_clips())
    capsys.readouterr()
    assert main(["list", str(tmp_path)]) == 0
    out = capsys.readouterr().out
    assert "walk_1p42" in out and f"{len(builtin_clips())} clip(s)" in out
    assert main(["list"]) == 0
    assert f"built-in synthetic clips: {len(builtin_clips())} clip(s)" in capsys.readouterr().out
