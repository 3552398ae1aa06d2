"""CMU's own ASF/AMC format: read, retargeted through the same path as BVH, found beside the AMC,
and one-line errors for bad files."""

from __future__ import annotations

import numpy as np
import pytest

from detach.character.body import DOF_NAMES
from detach.motion.asf_import import AsfError, read_asf, read_asf_amc
from detach.motion.bvh_import import read_bvh
from detach.motion.cli import main
from detach.motion.clip import load_clip
from detach.motion.retarget import load_map, retarget
from detach.motion.rotations import quat_from_axis_angle
from tests.test_motion_files import ASF_UNIT_M, THIGH_CM, write_amc, write_asf, write_cmu_bvh_like_asf

FRAMES = 6
ROOT_CM = np.stack([np.zeros(FRAMES), np.zeros(FRAMES), np.arange(FRAMES) * 2.0], axis=1)
KNEE_DEG = np.linspace(0.0, 100.0, FRAMES)
KNEE = DOF_NAMES.index("left_knee_y")


def _err(capsys) -> list[str]:
    captured = capsys.readouterr()
    assert "Traceback" not in captured.err
    return captured.err.strip().splitlines()


def test_asf_amc_import_through_the_cli(tmp_path, capsys):
    asf = write_asf(tmp_path / "subject" / "07.asf")
    amc = write_amc(tmp_path / "subject" / "07_03.amc", ROOT_CM, KNEE_DEG)
    assert main(["import", str(asf), str(amc), "--out", str(tmp_path / "out"), "--skill", "walk"]) == 0
    line = capsys.readouterr().out
    assert "07_03.npz" in line and "map=cmu_asf" in line and "at 120 fps" in line
    clip = load_clip(tmp_path / "out" / "07_03.npz")
    np.testing.assert_allclose(np.degrees(clip.dof_pos[:, KNEE]), KNEE_DEG, atol=1e-4)
    np.testing.assert_allclose(np.delete(clip.dof_pos, KNEE, axis=1), 0.0, atol=1e-4)
    np.testing.assert_allclose(clip.root_pos[:, 0], np.arange(FRAMES) * 0.02, atol=1e-6)  # metres, +X forward
    assert clip.fps == 120.0 and clip.meta["map"] == "cmu_asf"


def test_asf_amc_and_the_equivalent_bvh_give_the_same_clip():
    """CMU's BVH conversions put a joint at each bone's start with the bone's rotation: the ASF
    path and a BVH written that way agree to 1e-6."""
    from pathlib import Path
    import tempfile

    with tempfile.TemporaryDirectory() as tmp:
        tmp = Path(tmp)
        from_asf, _ = retarget(read_asf_amc(write_asf(tmp / "a.asf"), write_amc(tmp / "a.amc", ROOT_CM, KNEE_DEG)))
        bvh = read_bvh(write_cmu_bvh_like_asf(tmp / "a.bvh", ROOT_CM, KNEE_DEG))
        from_bvh, _ = retarget(bvh, load_map("cmu"), scale=ASF_UNIT_M)
    np.testing.assert_allclose(from_asf.dof_pos, from_bvh.dof_pos, atol=1e-6)
    np.testing.assert_allclose(from_asf.root_pos, from_bvh.root_pos, atol=1e-6)
    np.testing.assert_allclose(from_asf.body_pos, from_bvh.body_pos, atol=1e-6)


def test_units_and_bone_axes(tmp_path):
    """`length 0.45`: one unit = 0.0254/0.45 m; a bone with axis (0, 0, 90) turns its rx about
    world +Y (C Rx C^-1 with C = Rz(90))."""
    asf = write_asf(tmp_path / "s.asf", axis_deg={"ltibia": (0.0, 0.0, 90.0)})
    skeleton = read_asf(asf)
    assert skeleton.metres_per_unit == pytest.approx(0.0254 / 0.45)
    assert skeleton.bones[skeleton.index("lfemur")].length == pytest.approx(THIGH_CM / 100)
    data = read_asf_amc(asf, write_amc(tmp_path / "s.amc", ROOT_CM[:1], np.array([30.0])))
    tibia, femur = data.index("ltibia"), data.index("lfemur")
    expect = quat_from_axis_angle(np.array([0.0, 1.0, 0.0]), np.deg2rad(30.0))
    got = data.local_quat[0, tibia]
    np.testing.assert_allclose(got * np.sign(got[0]), expect, atol=1e-9)
    np.testing.assert_allclose(data.offsets[tibia], [0.0, -THIGH_CM / 100, 0.0], atol=1e-9)  # the femur's vector
    assert data.parents[tibia] == femur and data.frame_time == pytest.approx(1 / 120)
    text = asf.read_text().replace("length 0.45", "length 1.0").replace("angle deg", "angle rad")
    (tmp_path / "inch.asf").write_text(text)
    assert read_asf(tmp_path / "inch.asf").metres_per_unit == pytest.approx(0.0254)
    assert read_asf(tmp_path / "inch.asf").degrees is False


def test_the_asf_is_found_beside_the_amc(tmp_path, capsys):
    write_asf(tmp_path / "cmu" / "07.asf")
    write_asf(tmp_path / "cmu" / "08.asf")
    write_amc(tmp_path / "cmu" / "07_01.amc", ROOT_CM, KNEE_DEG)
    write_amc(tmp_path / "cmu" / "08_02.amc", ROOT_CM, KNEE_DEG)
    assert main(["import", str(tmp_path / "cmu"), "--out", str(tmp_path / "out")]) == 0  # a folder: both AMCs
    out = capsys.readouterr().out
    assert "[1/2]" in out and "[2/2]" in out and "imported 2 of 2 file(s)" in out
    assert (tmp_path / "out" / "07_01.npz").is_file() and (tmp_path / "out" / "08_02.npz").is_file()


@pytest.mark.parametrize(("case", "expect"), [
    ("no_asf", "no ASF skeleton for this AMC"),
    ("truncated", "frame 6 lacks"),
    ("unknown_bone", "bone 'tail' is not in the skeleton"),
    ("junk_asf", "not an ASF file (no :bonedata section)"),
    ("nan", "NaN or inf"),
    ("bad_count", "ltibia: expected 1 numbers, got 2"),
])
def test_bad_asf_amc_are_one_line_and_write_nothing(tmp_path, capsys, case, expect):
    folder = tmp_path / "in"
    asf = write_asf(folder / "09.asf")
    amc = write_amc(folder / "09_01.amc", ROOT_CM, KNEE_DEG)
    text = amc.read_text()
    if case == "no_asf":
        asf.unlink()
    elif case == "truncated":
        amc.write_text(text[: text.rindex("ltibia")])
    elif case == "unknown_bone":
        amc.write_text(text + "tail 1 2 3\n")
    elif case == "junk_asf":
        asf.write_text("hello\n")
    elif case == "nan":
        amc.write_text(text.replace("ltibia 20.000000", "ltibia nan", 1))
    elif case == "bad_count":
        amc.write_text(text.replace("ltibia 20.000000", "ltibia 20 1", 1))
    assert main(["import", str(amc), "--out", str(tmp_path / "out")]) == 2
    lines = _err(capsys)
    assert len(lines) == 1 and "in/09" in lines[0] and expect in lines[0], lines
    assert not (tmp_path / "out").exists() or not list((tmp_path / "out").iterdir())


def test_asf_errors_are_user_errors():
    assert issubclass(AsfError, ValueError)
