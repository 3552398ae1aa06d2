"""Declared support bodies (`meta["supports"]`): a hand or knee may carry the weight on a prop.

Placement plants them like feet; plausibility measures them like feet (on the support, at most
1 cm inside it, no sliding) and keeps every undeclared body under the stricter prop check."""

from __future__ import annotations

import numpy as np
import pytest

from detach.character.body import BODY_NAMES, DOF_NAMES
from detach.motion import builtin
from detach.motion.clip import MotionClip, clip_from_arrays
from detach.motion.kinematics import humanoid_fk
from detach.motion.placement import Terrain, ground_root
from detach.motion.plausibility import check_clip

HAND = BODY_NAMES.index("left_hand")


def _standing(frames: int = 3, slide: float = 0.0) -> MotionClip:
    """The first frame of `idle_breathe` held for `frames` frames, moved by `slide` m/s along x."""
    c = {c.name: c for c in builtin.builtin_clips()}["idle_breathe"]
    shift = np.zeros((frames, 3))
    shift[:, 0] = slide * np.arange(frames) / c.fps
    root = c.root_pos[:1] + shift
    body = c.body_pos[:1] + shift[:, None, :]
    return clip_from_arrays("probe", "idle", c.fps, root, np.repeat(c.root_quat[:1], frames, 0),
                            np.repeat(c.dof_pos[:1], frames, 0), body, {"synthetic": True})


def _with_block_under_hand(clip: MotionClip, depth: float, supports: list[str] | None,
                           length: float = 0.06) -> MotionClip:
    """`clip` with a block (6 cm wide, `length` m along x) under its left hand, the hand sphere
    `depth` m into the block's top."""
    hand = clip.body_pos[0, HAND]
    top = hand[2] - 0.04 + depth
    block = {"center": [float(hand[0]), float(hand[1]), top / 2], "half": [length / 2, 0.03, top / 2]}
    meta = dict(clip.meta, props=[block])
    if supports is not None:
        meta["supports"] = supports
    return clip_from_arrays(clip.name, clip.skill, clip.fps, clip.root_pos, clip.root_quat, clip.dof_pos,
                            clip.body_pos, meta)


def test_a_declared_hand_may_rest_on_a_prop():
    p = check_clip(_with_block_under_hand(_standing(), 0.008, ["left_hand"]))
    assert p.lowest_support == pytest.approx(-0.008, abs=1e-6)
    assert p.min_support_prop_distance == pytest.approx(-0.008, abs=1e-6)
    assert p.min_prop_distance > 0.0 and p.support_skate == 0.0 and not p.flags()


def test_an_undeclared_hand_on_a_prop_still_fails():
    p = check_clip(_with_block_under_hand(_standing(), 0.008, None))
    assert p.min_prop_distance == pytest.approx(-0.008, abs=1e-6) and p.worst_prop_body.startswith("left_hand")
    assert p.min_prop_distance < -0.005  # the built-in clips' bound for any body but the feet
    assert p.lowest_support == np.inf and p.min_support_prop_distance == np.inf


def test_a_declared_hand_sunk_into_a_prop_fails():
    p = check_clip(_with_block_under_hand(_standing(), 0.05, ["left_hand"]))
    assert p.lowest_support == pytest.approx(-0.05, abs=1e-6) and p.min_support_prop_distance < -0.01
    assert "BELOW" in p.flags()


def test_a_declared_hand_must_not_slide_on_the_prop():
    resting = _with_block_under_hand(_standing(), 0.0, ["left_hand"], length=0.4)
    moved = _standing(slide=1.0)  # the whole body slides 1 m/s; the block stays
    clip = clip_from_arrays("probe", "idle", moved.fps, moved.root_pos, moved.root_quat, moved.dof_pos,
                            moved.body_pos, resting.meta)
    assert check_clip(clip).support_skate == pytest.approx(1.0, rel=1e-6)


def test_a_climb_without_its_declared_supports_fails():
    """climb_0p86 hangs on its hands and knee with both feet in the air; undeclared, that is a
    support gap (and floating)."""
    c = {c.name: c for c in builtin.builtin_clips()}["climb_0p86"]
    meta = {k: v for k, v in c.meta.items() if k != "supports"}
    bare = clip_from_arrays(c.name, c.skill, c.fps, c.root_pos, c.root_quat, c.dof_pos, c.body_pos, meta)
    p = check_clip(bare)
    assert p.max_support_gap > 0.2 and p.floating_fraction > 0.1


def test_placement_plants_a_declared_support_body():
    """Feet tucked up and a hand on a box: without supports the root drops until a foot touches
    the floor; with the hand declared, the hand rests on the box top and stays where it is while
    the arm swings (the root moves instead)."""
    f = 20
    q = np.zeros((f, len(DOF_NAMES)))
    for s in ("left", "right"):
        q[:, DOF_NAMES.index(f"{s}_hip_y")] = -1.2
        q[:, DOF_NAMES.index(f"{s}_knee_y")] = 2.0
    q[:, DOF_NAMES.index("left_shoulder_y")] = np.linspace(-1.2, -0.8, f)  # arm forward, swinging
    quat = np.repeat([[1.0, 0.0, 0.0, 0.0]], f, 0)
    fk = humanoid_fk()
    rel = fk.run(np.zeros((f, 3)), quat, q)
    hand0 = rel.body_pos[0, HAND]
    terrain = Terrain([((hand0[0], hand0[1], 0.5), (0.15, 0.15, 0.5))])  # top at 1 m under the hand
    plain = ground_root(rel, terrain)
    assert (rel.foot_bottom + plain[:, 2:3]).min(axis=1) == pytest.approx(np.zeros(f), abs=1e-9)
    root = ground_root(rel, terrain, supports=("left_hand",))
    hand = rel.body_pos[:, HAND] + root
    assert hand[:, 2] - 0.04 == pytest.approx(np.full(f, 1.0), abs=1e-9)     # resting on the top
    assert np.abs(hand[:, :2] - hand[0, :2]).max() < 1e-9                    # planted
    assert np.ptp(root[:, 0]) > 0.05                                         # the body moves instead
