"""Built-in synthetic clips: generated fast and deterministically, kinematically plausible."""

from __future__ import annotations

import time

import numpy as np
import pytest
import torch

from detach.character.body import BODY_NAMES, dof_ranges
from detach.motion import builtin
from detach.motion.kinematics import humanoid_fk
from detach.motion.plausibility import check_clip, foot_clearance
from detach.motion.labels import MOTION_LABELS
from detach.skills import skill_class, skill_names


@pytest.fixture(scope="module")
def clips():
    builtin._builtin.cache_clear()
    t0 = time.perf_counter()
    out = builtin.builtin_clips()
    elapsed = time.perf_counter() - t0
    assert elapsed < 5.0, f"generating the built-in clips took {elapsed:.1f} s"
    return {c.name: c for c in out}


def test_labels_cover_every_task_group(clips):
    labels = {c.skill for c in clips.values()}
    assert labels == set(MOTION_LABELS)
    assert skill_names() == ("follow", "carry", "climb", "sit")
    assert all(set(skill_class(s).motion_labels) <= labels for s in skill_names())
    assert all(c.meta["synthetic"] for c in clips.values())


def test_deterministic(clips):
    again = builtin._RECIPES[2]()  # walk_1p42, regenerated from scratch
    ref = clips[again.name]
    np.testing.assert_array_equal(again.dof_pos, ref.dof_pos)
    np.testing.assert_array_equal(again.body_pos, ref.body_pos)


def test_body_positions_are_mujoco_fk(clips):
    c = clips["step_up_0p30"]
    fk = humanoid_fk().run(c.root_pos, c.root_quat, c.dof_pos)
    np.testing.assert_allclose(fk.body_pos, c.body_pos, atol=1e-9)


@pytest.mark.parametrize("name", ["idle_breathe", "idle_shift", "walk_1p42", "walk_1p48", "walk_1p90",
                                  "turn_left_90", "turn_right_90", "walk_turn_left", "walk_turn_right", "step_up_0p30",
                                  "step_up_0p45", "step_up_0p50", "sit_down", "sit_stand_up",
                                  "sit_down_0p35", "sit_stand_up_0p35", "sit_down_0p25", "sit_stand_up_0p25",
                                  "carry_walk", "carry_stand", "climb_0p70", "climb_0p86"])
def test_plausible(clips, name):
    c = clips[name]
    p = check_clip(c)
    assert p.lowest_foot > -0.01, p           # no foot ever in the floor / step
    assert p.max_support_gap < 0.02, p        # a foot is on its support in every frame
    assert p.range_violation == 0.0, p        # within dof_ranges()
    assert p.min_self_distance > 0.0, p       # no limb interpenetration (hands vs torso/thighs, ...)
    assert p.min_prop_distance > -0.005, p    # nothing but the feet inside the step / seat
    assert p.foot_skate < 0.5, p              # planted feet do not slide (m/s)
    assert p.lowest_support >= -0.01, p       # declared hands / knee: on their support, not in it
    assert p.min_support_prop_distance >= -0.01, p
    assert p.support_skate < 0.5, p           # and they do not slide while down
    assert not p.flags(), p
    rng = dof_ranges()
    assert (c.dof_pos >= rng[:, 0] - 1e-9).all() and (c.dof_pos <= rng[:, 1] + 1e-9).all()


def test_walking_speed_and_stance(clips):
    for name, lo, hi in (("walk_1p42", 1.4, 1.5), ("walk_1p48", 1.4, 1.5), ("walk_1p90", 1.85, 1.95)):
        c = clips[name]
        speed = np.linalg.norm(c.root_pos[-1, :2] - c.root_pos[0, :2]) / c.duration
        assert lo <= speed <= hi, (name, speed)
        assert abs(c.root_pos[-1, 1]) < 0.01  # straight ahead (+X)
        clear = foot_clearance(c)
        assert (clear.min(axis=1) < 0.02).all()  # the stance foot is on the ground in every frame
        assert (clear.max(axis=0) > 0.1).all()   # and each foot swings clear of it
    turn = clips["turn_left_90"]
    yaw = 2 * np.arctan2(turn.root_quat[:, 3], turn.root_quat[:, 0])
    assert yaw[-1] - yaw[0] == pytest.approx(np.pi / 2, abs=1e-3)


def test_sit_and_step_targets(clips):
    sit = clips["sit_down"]
    seat_top = sit.meta["props"][0]["center"][2] + sit.meta["props"][0]["half"][2]
    assert seat_top == pytest.approx(0.45)
    assert sit.root_pos[-1, 2] == pytest.approx(seat_top + 0.1, abs=0.01)  # pelvis 0.1 m above the seat
    for height in (0.45, 0.50):
        step = clips[f"step_up_0p{round(height * 100):02d}"]
        feet = step.body_pos[-1, [BODY_NAMES.index("left_foot"), BODY_NAMES.index("right_foot")], 2]
        assert feet == pytest.approx([height + 0.075] * 2, abs=0.005)  # both ankles above the step top


@pytest.mark.parametrize("seat,task", [(0.45, "LH1's chair"), (0.35, "LH2's sofa"), (0.25, "LH3's bed")])
def test_sit_clips_at_every_lh_seat_height(clips, seat, task):
    """The Sit clips reach each LH task's seat, sitting down and standing up: the pelvis ends
    (or starts) 0.1 m above the seat's top, the sit target's height above it."""
    suffix = "" if seat == 0.45 else f"_0p{round(seat * 100):02d}"
    for name, frame in ((f"sit_down{suffix}", -1), (f"sit_stand_up{suffix}", 0)):
        c = clips[name]
        top = c.meta["props"][0]["center"][2] + c.meta["props"][0]["half"][2]
        assert top == pytest.approx(seat), (task, name)
        assert c.root_pos[frame, 2] == pytest.approx(seat + 0.1, abs=0.01), (task, name)


def test_a_step_up_clip_at_the_climb_tasks_height(clips):
    """The style reward's Climb clips reach the climb task's 0.50 m platform, LH1's 0.70 m box
    and LH3's 0.86 m step box (the last two climbed with hands and a knee: `builtin._climb`)."""
    heights = sorted(c.meta["props"][0]["half"][2] * 2 for c in clips.values() if c.skill == "step_up")
    for target in (0.50, 0.70, 0.86):
        assert min(abs(h - target) for h in heights) <= 0.005, (target, heights)


@pytest.mark.parametrize("name,height,size", [("climb_0p70", 0.70, 0.6), ("climb_0p86", 0.86, 0.8)])
def test_high_box_climbs_end_standing_on_the_top(clips, name, height, size):
    """LH1's (0.6 x 0.6 x 0.7 m) and LH3's (0.8 x 0.8 x 0.86 m) boxes: the clip starts standing
    on the floor in front of the box and ends upright on its top, both feet on it, the pelvis at
    standing height above it; hands and the left knee are the declared extra supports."""
    c = clips[name]
    assert c.skill == "step_up" and c.fps == 30.0
    (box,) = c.meta["props"]
    assert box["half"] == pytest.approx([size / 2, size / 2, height / 2])
    top = box["center"][2] + box["half"][2]
    assert top == pytest.approx(height)
    assert set(c.meta["supports"]) == {"left_hand", "right_hand", "left_shin"}
    feet = [BODY_NAMES.index("left_foot"), BODY_NAMES.index("right_foot")]
    assert c.body_pos[0, feet, 2] == pytest.approx([0.075] * 2, abs=0.005)      # on the floor
    assert (c.body_pos[0, feet, 0] < box["center"][0] - box["half"][0] - 0.15).all()  # in front of it
    assert c.root_pos[-1, 2] - top == pytest.approx(0.93, abs=0.01)             # upright on the top
    assert c.body_pos[-1, feet, 2] == pytest.approx([top + 0.075] * 2, abs=0.005)
    inside = np.abs(c.body_pos[-1, feet, :2] - np.array(box["center"][:2])) < np.array(box["half"][:2]) - 0.05
    assert inside.all()
    assert abs(c.root_quat[-1, 2]) < 0.02  # pelvis nearly level (small pitch)


def test_default_motion_lib(clips):
    lib = builtin.default_motion_lib("cpu")
    assert lib.num_clips == len(clips)
    ids, w = lib.sample_windows(32, steps=10, skills=skill_class("climb").motion_labels)
    assert set(lib.clip_skill[ids].tolist()) <= {MOTION_LABELS.index("step_up"), MOTION_LABELS.index("walk")}
    assert w.key_body_pos.shape == (32, 10, 4, 3) and torch.isfinite(w.dof_vel).all()
