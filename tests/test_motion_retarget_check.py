"""Retargeting that checks itself (issue 61, item 1): standing, walking and seated motions in
every skeleton family, imported with `--map auto`, meet the targets, and the import line and
`list --check` print them.

Before: a seated clip whose hips flex to 105 degrees (mocap jitter on every joint) ran its
seated frames on the other Euler branch of the hips: 8.5% of angles clipped (left_hip_x in 68%
of frames by 1.56 rad, left_hip_z by 1.38 rad), a foot on the floor in 3-60% of frames, knees
16 degrees off; a real Hips/Chest sit recording showed the same (7.4%, 2.9 and 2.4 rad).
"""

from __future__ import annotations

import re

import numpy as np
import pytest

from detach.motion.cli import main
from detach.motion.clip import load_clip
from tests.mocap_motions import KINDS, write_motion_asf_amc, write_motion_bvh
from tests.test_motion_files import FAMILIES

SKILL = {"stand": "idle", "walk": "walk", "sit": "sit"}
CASES = [(family, kind) for family in (*FAMILIES, "cmu_asf") for kind in KINDS]


def _import(tmp_path, capsys, family: str, kind: str, **motion) -> tuple[str, dict]:
    if family == "cmu_asf":
        paths = [str(p) for p in write_motion_asf_amc(tmp_path / "src", kind, **motion)]
    else:
        paths = [str(write_motion_bvh(tmp_path / "src" / f"{kind}.bvh", family, kind, **motion))]
    assert main(["import", *paths, "--out", str(tmp_path / "out"), "--skill", SKILL[kind]]) == 0
    line = capsys.readouterr().out.strip()
    clip = load_clip(tmp_path / "out" / f"{kind}.npz")
    assert clip.meta["map"] == family
    return line, clip.meta["check"]


@pytest.mark.parametrize(("family", "kind"), CASES, ids=lambda v: str(v))
def test_every_family_meets_the_targets(tmp_path, capsys, family, kind):
    """At most 1% of angles clipped, a foot at ankle height in at least 90% of the frames of
    standing and seated clips, mean bone-direction error under 10 degrees; the import line
    prints them and no CHECK warning."""
    line, check = _import(tmp_path, capsys, family, kind)
    assert check["clipped_fraction"] <= 0.01, line
    if kind != "walk":
        assert check["grounded_fraction"] >= 0.9, line
    assert check["bone_error_deg"] < 10.0, line
    assert max(j["bone_error_deg"] for j in check["joints"].values()) < 10.0, line
    assert "CHECK" not in line and "FLOATING" not in line, line
    mean = float(re.search(r"bones off by ([\d.]+) deg on average \(worst: (\w+) ([\d.]+) deg", line).group(1))
    assert mean == pytest.approx(check["bone_error_deg"], abs=0.05)


def test_a_seated_clip_past_90_degrees_keeps_its_hips_on_the_right_branch(tmp_path, capsys):
    """The bug's clip in the Hips/Chest family (ZXY channels): hips flexed to 105 degrees.
    The thighs point where the source's do (a few degrees at most) in every frame, and the
    hip angles stay near the source's flexion instead of the other Euler branch."""
    line, check = _import(tmp_path, capsys, "hips_chest", "sit")
    for side in ("left", "right"):
        assert check["joints"][f"{side}_hip"]["max_error_deg"] < 3.0, line
        assert check["joints"][f"{side}_knee"]["max_error_deg"] < 3.0, line
    clip = load_clip(tmp_path / "out" / "sit.npz")
    from detach.character.body import DOF_NAMES

    flex = np.degrees(clip.dof_pos[-30:, DOF_NAMES.index("left_hip_y")])
    assert (flex < -100).all() and (flex > -112).all(), flex  # seated: 105 degrees of flexion
    assert "a foot on the floor in 100% of frames" in line, line


def test_what_the_humanoid_cannot_follow_is_reported(tmp_path, capsys):
    """Knees 9 degrees apart with the hips flexed 105 degrees: our hip's hinges nest x, y, z, so
    moving a flexed thigh outward needs hinge x past its bound. The import says so (the hips
    as worst joints, a CHECK warning) instead of silently flailing; the legs stay close (bone
    errors of a few degrees, not the 90+ of the wrong branch)."""
    line, check = _import(tmp_path, capsys, "hips_chest", "sit", knees_apart_deg=9.0)
    assert "(CHECK: " in line and "clipped > 1%" in line, line
    worst = re.search(r"\(worst: (\w+) ", line).group(1)
    assert worst in ("left_hip", "right_hip"), line
    assert check["joints"]["left_hip"]["clipped_frames"] > 0.5
    assert check["bone_error_deg"] < 10.0 and check["joints"]["left_hip"]["max_error_deg"] < 10.0, line


def test_list_check_prints_the_retarget_check(tmp_path, capsys):
    """`list --check` shows each imported clip's clipped share, mean bone error and worst joint,
    flags RETARGET when a target is missed, and '-' for clips without a source (built-in)."""
    for kind, apart in (("sit", 3.0), ("stand", 3.0)):
        write_motion_bvh(tmp_path / "src" / f"{kind}.bvh", "mixamo", kind, knees_apart_deg=apart)
    write_motion_bvh(tmp_path / "src" / "wide.bvh", "mixamo", "sit", knees_apart_deg=9.0)
    assert main(["import", str(tmp_path / "src"), "--out", str(tmp_path / "out"), "--skill", "sit"]) == 0
    assert main(["builtin", "--out", str(tmp_path / "out")]) == 0
    capsys.readouterr()
    assert main(["list", str(tmp_path / "out"), "--check"]) == 0
    out = capsys.readouterr().out.splitlines()
    head = out[1].split()
    assert head[-4:] == ["clip%", "bone_deg", "worst_joint", "flags"]
    k = head.index("clip%")
    rows = {line.split()[0]: line.split() for line in out[2:]}
    sit, wide = rows["sit"], rows["wide"]
    assert float(sit[k]) <= 1.0 and float(sit[k + 1]) < 10.0 and "RETARGET" not in sit[k + 3:]
    assert float(wide[k]) > 1.0 and "RETARGET" in wide[k + 3:]
    assert wide[k + 2].split(":")[0] in ("left_hip", "right_hip")
    assert rows["walk_1p42"][k:k + 3] == ["-", "-", "-"] and "RETARGET" not in rows["walk_1p42"]
