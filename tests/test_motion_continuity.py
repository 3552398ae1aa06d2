"""Angles made continuous before clipping (issue: a knee passing +-pi was clipped straight and the
whole clip lifted 0.29 m), per-hinge clipping reports, and `list --check` flagging floating feet."""

from __future__ import annotations

import numpy as np
import pytest

from detach.character.body import DOF_NAMES, JOINT_GROUPS
from detach.motion.angle_continuity import (clip_to_ranges, continuous_euler_xyz, continuous_track,
                                            nearest_equivalent, nearest_to_range)
from detach.motion.cli import main
from detach.motion.clip import load_clip, save_clip
from detach.motion.plausibility import check_clip
from detach.motion.rotations import matrix_from_euler_xyz
from tests.test_motion_files import write_bvh

KNEE = (0.0, np.deg2rad(160.0))


def test_nearest_equivalents():
    assert nearest_equivalent(-4.36, 1.93) == pytest.approx(-4.36 + 2 * np.pi)
    assert nearest_to_range(-4.36, *KNEE) == pytest.approx(-4.36 + 2 * np.pi)  # 1.92 rad: inside
    assert nearest_to_range(3.5, -0.5, 0.5) == pytest.approx(3.5 - 2 * np.pi)  # -2.78: nearer the range
    np.testing.assert_allclose(nearest_to_range(np.array([0.1, 7.0]), -1.0, 1.0), [0.1, 7.0 - 2 * np.pi])


def test_the_knee_of_the_issue_stays_bent():
    """1.93 -> -4.36 rad between two frames is the same rotation: the track stays at ~1.93."""
    track = continuous_track(np.array([1.90, 1.93, -4.36, -4.30, 1.98]), *KNEE)
    np.testing.assert_allclose(track, [1.90, 1.93, -4.36 + 2 * np.pi, -4.30 + 2 * np.pi, 1.98])
    # the first frame starts next to the range, whatever 2 pi multiple the extraction gave
    np.testing.assert_allclose(continuous_track(np.array([-4.36, -4.30]), *KNEE), [1.923185, 1.983185], atol=1e-6)


def test_euler_solutions_follow_the_previous_frame_through_pi_over_2():
    """b runs 1.2 -> 1.9 rad (past pi/2): the principal decomposition jumps to the other branch
    (a + pi, pi - b, c + pi); the continuous one keeps a = 0.2, c = 0.3 and b rising."""
    b = np.sort(np.append(np.linspace(1.2, 1.9, 15), np.pi / 2))  # one frame exactly at gimbal lock
    mats = matrix_from_euler_xyz(np.full_like(b, 0.2), b, np.full_like(b, 0.3))
    ranges = np.array([[-1.0, 1.0], [-2.4, 2.4], [-1.0, 1.0]])
    angles = continuous_euler_xyz(mats, ranges)
    np.testing.assert_allclose(angles[:, 0], 0.2, atol=1e-9)
    np.testing.assert_allclose(angles[:, 1], b, atol=1e-9)
    np.testing.assert_allclose(angles[:, 2], 0.3, atol=1e-9)
    np.testing.assert_allclose(matrix_from_euler_xyz(*angles.T), mats, atol=1e-12)


def test_first_frame_takes_the_euler_solution_inside_the_ranges():
    """(a, b, c) = (0.1, 2.0, 0.2) and (0.1 + pi, pi - 2.0, 0.2 + pi) are one rotation; only
    the first fits ranges whose b reaches 2.0."""
    mats = matrix_from_euler_xyz(np.array([0.1]), np.array([2.0]), np.array([0.2]))
    angles = continuous_euler_xyz(mats, np.array([[-0.6, 0.6], [-0.8, 2.2], [-0.8, 0.8]]))
    np.testing.assert_allclose(angles[0], [0.1, 2.0, 0.2], atol=1e-9)


def test_clip_report_names_each_clipped_hinge():
    ranges = np.array([[0.0, 1.0], [-1.0, 1.0]])
    dof = np.array([[0.5, 0.0], [-0.3, 0.0], [-0.1, 1.5], [0.2, 0.0]])
    clipped, report = clip_to_ranges(dof, ranges, ("knee", "hip"))
    np.testing.assert_allclose(clipped[:, 0], [0.5, 0.0, 0.0, 0.2])
    assert report.fraction == pytest.approx(3 / 8)
    assert report.worst() == [("knee", 0.5, pytest.approx(0.3)), ("hip", 0.25, pytest.approx(0.5))]
    assert report.as_dict() == {"knee": {"frames": 0.5, "max_excess_deg": pytest.approx(17.19, abs=0.01)},
                                "hip": {"frames": 0.25, "max_excess_deg": pytest.approx(28.65, abs=0.01)}}


def squat(path, glitch: bool):
    """10 frames of a squat (thighs 20 deg forward, knees 100 deg); with `glitch`, frame 5 writes
    both knees on the other Euler branch (the same rotation)."""
    frames = 10
    branch = np.zeros(frames, dtype=bool)
    right = np.tile([0.0, 100.0, 0.0], (frames, 1))
    if glitch:
        branch[5] = True
        right[5] = (180.0, 80.0, 180.0)
    thighs = np.tile([0.0, -20.0, 0.0], (frames, 1))
    return write_bvh(path, "cmu", np.zeros((frames, 3)), np.full(frames, 100.0), knee_branch=branch,
                     channels={"r_shin": right, "l_thigh": thighs, "r_thigh": thighs})


def test_a_knee_on_the_other_euler_branch_keeps_the_clip_on_the_floor(tmp_path, capsys):
    """Before: that frame's knees were clipped straight, the feet dipped, the clip was lifted
    ~0.25 m and floated in 9 of 10 frames while `list --check` reported it clean."""
    assert main(["import", str(squat(tmp_path / "squat.bvh", True)), "--out", str(tmp_path / "out")]) == 0
    assert main(["import", str(squat(tmp_path / "clean.bvh", False)), "--out", str(tmp_path / "out")]) == 0
    line = capsys.readouterr().out.splitlines()[0]
    assert "0.0% of angles clipped" in line and "a foot on the floor in 100% of frames" in line, line
    glitch, clean = load_clip(tmp_path / "out" / "squat.npz"), load_clip(tmp_path / "out" / "clean.npz")
    for side in ("left", "right"):
        np.testing.assert_allclose(glitch.dof_pos[:, DOF_NAMES.index(f"{side}_knee_y")], np.deg2rad(100), atol=1e-6)
    np.testing.assert_allclose(glitch.root_pos, clean.root_pos, atol=1e-6)
    check = check_clip(glitch)
    assert check.floating_fraction == 0.0 and check.flags() == [] and abs(check.lowest_foot) < 1e-6


def test_list_check_flags_a_floating_clip(tmp_path, capsys):
    assert main(["import", str(squat(tmp_path / "squat.bvh", False)), "--out", str(tmp_path)]) == 0
    clip = load_clip(tmp_path / "squat.npz")
    clip.name = "lifted"
    clip.root_pos = clip.root_pos + [0.0, 0.0, 0.29]
    clip.body_pos = clip.body_pos + [0.0, 0.0, 0.29]
    save_clip(clip, tmp_path / "lifted.npz")
    capsys.readouterr()
    assert main(["list", str(tmp_path), "--check"]) == 0
    rows = {line.split()[0]: line for line in capsys.readouterr().out.splitlines()[2:]}
    assert rows["lifted"].endswith("FLOAT") and "100.0" in rows["lifted"].split()
    assert rows["squat"].endswith(" -")


def test_hyperextension_is_clipped_and_reported_per_hinge(tmp_path, capsys):
    """A knee bent backwards by 20 deg is outside 0..160 deg: clipped, and the import line and
    the clip's meta say which hinge, in how many frames and by how much."""
    path = write_bvh(tmp_path / "hyper.bvh", "cmu", np.zeros((4, 3)), np.array([0.0, -20.0, -20.0, 10.0]))
    assert main(["import", str(path), "--out", str(tmp_path)]) == 0
    line = capsys.readouterr().out
    assert "left_knee_y 50% of frames (max 0.35 rad over)" in line
    clip = load_clip(tmp_path / "hyper.npz")
    assert clip.meta["clipping"] == {"left_knee_y": {"frames": 0.5, "max_excess_deg": pytest.approx(20.0, abs=0.01)}}
    np.testing.assert_allclose(clip.dof_pos[:, DOF_NAMES.index("left_knee_y")], [0, 0, 0, np.deg2rad(10)], atol=1e-6)


def test_every_joint_group_is_covered():
    """The hinge-like rule (knees) and Euler rule (others) between them handle every group."""
    assert {g.axes for g in JOINT_GROUPS} <= {"xyz", "y"}
