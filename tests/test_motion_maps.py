"""Joint maps: the shipped skeleton families, `--map auto`, scale/axes auto, prefixes, custom maps,
and errors that list every missing joint."""

from __future__ import annotations

import numpy as np
import pytest

from detach.character.body import DOF_NAMES
from detach.motion.cli import main
from detach.motion.clip import load_clip
from detach.motion.joint_map import RetargetError, available_maps, bind, choose_map, load_map, resolve
from tests.test_motion_files import FAMILIES, skeleton, write_bvh

FRAMES = 5
ROOT_CM = np.stack([np.zeros(FRAMES), np.zeros(FRAMES), np.arange(FRAMES) * 2.0], axis=1)  # 2 cm/frame forward
KNEE_DEG = np.linspace(0.0, 90.0, FRAMES)
KNEE = DOF_NAMES.index("left_knee_y")
SOURCES = [(family, {}) for family in FAMILIES] + [(family, {"z_up": True, "unit": 100.0}) for family in FAMILIES
                                                 if family != "cmu"] + [("mixamo", {"prefix": "mixamorig:"})]


def _err(capsys) -> str:
    captured = capsys.readouterr()
    lines = captured.err.strip().splitlines()
    assert len(lines) == 1 and "Traceback" not in captured.err, captured.err
    return lines[0]


def test_shipped_maps_load():
    assert {"cmu", "cmu_asf", "cmu_daz", "mixamo", "hips_chest", "biovision"} <= set(available_maps())
    for name in available_maps():
        assert load_map(name).joints


@pytest.mark.parametrize(("family", "variant"), SOURCES, ids=lambda v: str(v))
def test_auto_map_imports_every_family(tmp_path, capsys, family, variant):
    """Same human, same motion, in each naming family, Y up in cm or Z up in metres, with or
    without a `mixamorig:` prefix: `--map auto` finds the family's map, and the clip is the same."""
    path = write_bvh(tmp_path / "m.bvh", family, ROOT_CM, KNEE_DEG, **variant)
    assert main(["import", str(path), "--out", str(tmp_path)]) == 0
    assert f"map={family}" in capsys.readouterr().out
    clip = load_clip(tmp_path / "m.npz")
    np.testing.assert_allclose(np.degrees(clip.dof_pos[:, KNEE]), KNEE_DEG, atol=1e-4)
    np.testing.assert_allclose(np.delete(clip.dof_pos, KNEE, axis=1), 0.0, atol=1e-4)  # arms hang like ours
    # 2 cm per frame forward (+X); the legs are exactly ours (scale auto -> 0.01 m/cm; cmu: 0.056 m/unit)
    step = 0.02 if family != "cmu" else 2.0 * 0.056
    np.testing.assert_allclose(clip.root_pos[:, 0], np.arange(FRAMES) * step, atol=1e-6)
    np.testing.assert_allclose(clip.root_pos[:, 1], 0.0, atol=1e-6)


def test_hips_under_a_static_reference_root(tmp_path, capsys):
    """Some exporters put a still `Reference` ROOT above Hips and the motion on Hips' own
    position channels: the pelvis follows Hips, not the file's ROOT."""
    path = write_bvh(tmp_path / "plain.bvh", "mixamo", ROOT_CM, KNEE_DEG)
    lines = path.read_text().splitlines()
    start = lines.index("MOTION")
    header = ["HIERARCHY", "ROOT Reference", "{", "  OFFSET 0 0 0",
              "  CHANNELS 6 Xposition Yposition Zposition Zrotation Xrotation Yrotation",
              lines[1].replace("ROOT", "JOINT"), *lines[2:start], "}"]
    frames = ["0 0 0 0 0 0 " + line for line in lines[start + 3:]]
    wrapped = tmp_path / "wrapped.bvh"
    wrapped.write_text("\n".join(header + lines[start:start + 3] + frames) + "\n")
    assert main(["import", str(path), str(wrapped), "--out", str(tmp_path)]) == 0
    plain, moved = load_clip(tmp_path / "plain.npz"), load_clip(tmp_path / "wrapped.npz")
    np.testing.assert_allclose(moved.root_pos, plain.root_pos, atol=1e-6)
    np.testing.assert_allclose(moved.dof_pos, plain.dof_pos, atol=1e-6)


def test_names_match_behind_a_namespace_prefix():
    names = ["mixamorig:Hips", "mixamorig:Spine", "Other:Head"]
    assert resolve(("Hips",), names) == "mixamorig:Hips" and resolve(("Head",), names) == "Other:Head"
    assert resolve(("Spine2", "Spine"), names) == "mixamorig:Spine" and resolve(("Neck",), names) is None


def test_auto_prefers_the_map_whose_detect_joints_are_present():
    """A CMU file also has every joint the Mixamo map needs; LHipJoint/LowerBack decide."""
    cmu = [j.name for j in skeleton("cmu")]
    mixamo = [j.name for j in skeleton("mixamo")]
    bind(load_map("mixamo"), cmu, "cmu.bvh")  # fits ...
    assert choose_map(cmu, "cmu.bvh").map.name == "cmu"  # ... but is not chosen
    assert choose_map(mixamo, "m.bvh").map.name == "mixamo"


def test_a_map_lists_every_missing_joint(tmp_path, capsys):
    path = write_bvh(tmp_path / "style.bvh", "hips_chest", ROOT_CM, KNEE_DEG)
    assert main(["import", str(path), "--map", "mixamo", "--out", str(tmp_path)]) == 2
    line = _err(capsys)
    assert line.startswith("detach-motion: error: ") and "style.bvh: map 'mixamo' needs 13 joint(s)" in line
    for joint in ("RightArm", "RightForeArm", "LeftUpLeg", "LeftLeg", "LeftFoot", "Spine2|Spine1|Spine"):
        assert joint in line
    assert "docs/MOCAP.md" in line and "file joints: Hips, Chest" in line
    assert not list(tmp_path.glob("*.npz"))


def test_no_shipped_map_fits(tmp_path, capsys):
    path = write_bvh(tmp_path / "odd.bvh", "biovision", ROOT_CM, KNEE_DEG)
    path.write_text(path.read_text().replace("LeftLowLeg", "LeftShin"))
    assert main(["import", str(path), "--out", str(tmp_path)]) == 2
    line = _err(capsys)
    assert "odd.bvh: no shipped joint map fits this skeleton" in line and "biovision lacks LeftLowLeg" in line
    assert "mixamo lacks" in line and "--map FILE.yaml" in line


def test_a_custom_map_with_candidates_auto_scale_and_explicit_axes(tmp_path, capsys):
    """The documented format: renamed knee fixed by a user map (lists of candidates, auto scale)."""
    path = write_bvh(tmp_path / "odd.bvh", "biovision", ROOT_CM, KNEE_DEG)
    path.write_text(path.read_text().replace("LeftLowLeg", "LeftShin"))
    text = load_map("biovision")
    assert text.scale is None and text.axes is None
    custom = tmp_path / "mine.yaml"
    custom.write_text((load_map.__globals__["MAPS_DIR"] / "biovision.yaml").read_text()
                      .replace("axes: auto", "axes: [z, x, y]")
                      .replace("{bvh: LeftUpLeg, aim: LeftLowLeg}", "{bvh: LeftUpLeg, aim: [LeftLowLeg, LeftShin]}")
                      .replace("{bvh: LeftLowLeg, aim: LeftFoot}", "{bvh: [LeftLowLeg, LeftShin], aim: LeftFoot}"))
    assert main(["import", str(path), "--map", str(custom), "--out", str(tmp_path)]) == 0
    assert "map=mine" in capsys.readouterr().out
    np.testing.assert_allclose(np.degrees(load_clip(tmp_path / "odd.npz").dof_pos[:, KNEE]), KNEE_DEG, atol=1e-4)


@pytest.mark.parametrize(("text", "expect"), [
    ("scale: -1\naxes: auto\nroot: Hips\njoints: {}\n", "scale must be a positive number"),
    ("scale: auto\naxes: [x, x, y]\nroot: Hips\njoints: {}\n", "is not a rotation"),
    ("scale: auto\naxes: auto\nroot: [Hips, 3]\njoints: {}\n", "root: expected a source joint name or a list"),
    ("scale: auto\naxes: auto\nroot: Hips\njoints: {tail: Tail}\n", "joints.tail: not a joint of the humanoid"),
    ("scale: auto\naxes: auto\nroot: Hips\njoints: {}\nextra: 1\n", "unknown key(s) extra"),
    ("scale: auto\naxes: auto\njoints: {}\n", "missing key(s) root"),
])
def test_map_file_errors_name_the_file(tmp_path, text, expect):
    bad = tmp_path / "bad.yaml"
    bad.write_text(text)
    with pytest.raises(RetargetError) as e:
        load_map(bad)
    assert str(e.value).startswith(str(bad)) and expect in str(e.value) and "\n" not in str(e.value)


def test_unknown_map_name_lists_the_shipped_ones(tmp_path, capsys):
    path = write_bvh(tmp_path / "m.bvh", "mixamo", ROOT_CM, KNEE_DEG)
    assert main(["import", str(path), "--map", "nosuchmap"]) == 2
    line = _err(capsys)
    assert "nosuchmap: unknown joint map; shipped maps: biovision, cmu" in line and "auto" in line
