"""The numpy BVH reader against bvhio (the maintained reference implementation of the same
semantics) on every kind of test file, and its speed on a CMU-length file."""

from __future__ import annotations

import time
import warnings
from pathlib import Path

import numpy as np
import pytest

from detach.motion.bvh_import import BvhError, read_bvh
from tests.test_motion_files import FAMILIES, write_bvh

DATA = Path(__file__).parent / "data"


def read_with_bvhio(path: Path):
    """(names, offsets, frame_time, local wxyz quats [F, J, 4], root positions [F, 3]) via bvhio."""
    with warnings.catch_warnings():
        warnings.simplefilter("ignore", PendingDeprecationWarning)
        import bvhio

    container = bvhio.readAsBvh(str(path))
    joints = []

    def walk(j) -> None:
        joints.append(j)
        for child in j.Children:
            walk(child)

    walk(container.Root)
    quat = np.stack([[list(kf.Rotation) for kf in j.Keyframes] for j in joints], axis=1)
    root = np.array([list(kf.Position) for kf in container.Root.Keyframes])
    return ([j.Name for j in joints], np.array([list(j.Offset) for j in joints]), container.FrameTime, quat, root)


def motions(tmp: Path) -> list[Path]:
    rng = np.random.default_rng(0)
    frames = 7
    root = rng.normal(scale=20.0, size=(frames, 3))
    knee = rng.uniform(-30, 170, frames)
    files = [DATA / "cmu_knee.bvh"]
    for family in FAMILIES:
        channels = {"l_thigh": rng.uniform(-180, 180, (frames, 3)), "r_upper_arm": rng.uniform(-180, 180, (frames, 3))}
        files.append(write_bvh(tmp / f"{family}.bvh", family, root, knee, channels=channels,
                               knee_branch=np.arange(frames) % 2 == 1))
    files.append(write_bvh(tmp / "zup.bvh", "mixamo", root, knee, z_up=True, unit=100.0, prefix="mixamorig:"))
    return files


def test_same_numbers_as_bvhio(tmp_path):
    for path in motions(tmp_path):
        ours = read_bvh(path)
        names, offsets, frame_time, quat, root = read_with_bvhio(path)
        assert ours.names == names, path
        np.testing.assert_allclose(ours.offsets, offsets, atol=1e-5, err_msg=str(path))
        assert ours.frame_time == pytest.approx(frame_time)
        np.testing.assert_allclose(ours.root_pos, root, atol=1e-4, err_msg=str(path))
        quat = quat / np.linalg.norm(quat, axis=-1, keepdims=True)
        dots = np.abs(np.sum(ours.local_quat * quat, axis=-1))  # q and -q are one rotation
        np.testing.assert_allclose(dots, 1.0, atol=1e-6, err_msg=str(path))


def test_hierarchy_parents_and_root_offset(tmp_path):
    text = (DATA / "cmu_knee.bvh").read_text().replace("ROOT Hips\n{\n  OFFSET 0.0 0.0 0.0\n  CHANNELS 6 Xposition "
                                                        "Yposition Zposition Zrotation Yrotation Xrotation",
                                                        "ROOT Hips\n{\n  OFFSET 1.0 2.0 3.0\n  CHANNELS 3 "
                                                        "Zrotation Yrotation Xrotation")
    lines = text.splitlines()
    start = lines.index("Frame Time: 0.0333333") + 1
    lines[start:] = [" ".join(line.split()[3:]) for line in lines[start:]]
    path = tmp_path / "no_root_motion.bvh"
    path.write_text("\n".join(lines) + "\n")
    data = read_bvh(path)
    np.testing.assert_allclose(data.root_pos, np.tile([1.0, 2.0, 3.0], (3, 1)))  # no position channels: OFFSET
    assert data.parents[data.index("LeftLeg")] == data.index("LeftUpLeg") and data.parents[0] == -1


@pytest.mark.parametrize(("mutate", "expect"), [
    (lambda t: t.replace("CHANNELS 3 Zrotation Yrotation Xrotation", "CHANNELS 3 Zrotation Yrotation Wrotation", 1),
     "bad CHANNELS"),
    (lambda t: t.replace("OFFSET 0.0 -7.5 0.0", "OFFSET 0.0 x 0.0", 1), "OFFSET values must be numbers"),
    (lambda t: t.replace("JOINT LeftLeg", "JOINT LeftUpLeg", 1), "duplicate joint name(s) LeftUpLeg"),
    (lambda t: t.replace("Frame Time: 0.0333333", "Frame Time: 0"), "Frame Time must be > 0"),
    (lambda t: t.replace("0 17 1 0", "0 17 nan 0"), "NaN or inf"),
])
def test_malformed_files_are_one_line(tmp_path, mutate, expect):
    path = tmp_path / "bad.bvh"
    path.write_text(mutate((DATA / "cmu_knee.bvh").read_text()))
    with pytest.raises(BvhError) as e:
        read_bvh(path)
    assert str(e.value).startswith(str(path)) and expect in str(e.value) and "\n" not in str(e.value)


def test_a_cmu_length_file_reads_and_imports_in_seconds(tmp_path):
    """12,000 frames (100 s at 120 fps) of a 26-joint skeleton: bvhio alone took 9.7 s to read
    it and the angle continuity loop 8 s; the whole import now takes a few seconds."""
    from detach.motion.retarget import retarget

    frames = 12_000
    t = np.arange(frames) / 120.0
    thigh = np.stack([5 * np.sin(t), -20 * np.sin(3 * t), 3 * np.cos(t)], axis=1)
    path = write_bvh(tmp_path / "long.bvh", "cmu", np.stack([10 * np.sin(t), 0 * t, 80 * t], axis=1),
                     40 + 40 * np.sin(3 * t), fps=120.0, channels={"l_thigh": thigh, "r_thigh": -thigh})
    start = time.perf_counter()
    data = read_bvh(path)
    read_s = time.perf_counter() - start
    clip, _ = retarget(data)
    total_s = time.perf_counter() - start
    assert clip.num_frames == frames
    assert read_s < 5.0 and total_s < 20.0, (read_s, total_s)  # generous: 2 shared, busy cores
