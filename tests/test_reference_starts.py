"""Reference-state starts (`env.init: random | mixed`) draw from clips the start can stand in:
the first subtask's skill's clips without a prop, not a frame on top of a step or on a seat
that is not there (which started the humanoid 0.5 m in the air or sitting on nothing)."""

from __future__ import annotations

from pathlib import Path

import pytest
import torch

from detach.config import resolve
from detach.motion.builtin import default_motion_lib
from detach.train.motion_bridge import reset_reference_sampler, start_clip_labels, start_clip_probs
from detach.train.start_library import make_training_env

TASKS = Path(__file__).resolve().parents[1] / "configs" / "tasks"


def _start_heights(task: str, *overrides: str) -> torch.Tensor:
    torch.set_num_threads(1)
    cfg = resolve(TASKS / f"{task}.yaml", "mlp", ["env.init=random", *overrides], seed=2)
    env = make_training_env(cfg, num_envs=64, verbose=False)
    env.set_reference_sampler(reset_reference_sampler(default_motion_lib(), start_clip_labels(cfg)))
    env.reset()
    return env.state.root_pos[:, 2].clone()


@pytest.mark.parametrize("task", ["follow", "sit"])
def test_reference_starts_stand_on_the_floor(task):
    heights = _start_heights(task)
    assert heights.min() > 0.8 and heights.max() < 1.0, heights  # walking, turning or standing


def test_every_clip_on_request_starts_some_in_the_air_or_seated():
    heights = _start_heights("follow", "env.init_clips=all")
    assert heights.max() > 1.2 or heights.min() < 0.7, heights


def test_prop_free_starts_stand_on_the_floor_in_every_prop_free_pose():
    heights = _start_heights("carry", "env.init_clips=prop_free")
    assert heights.min() > 0.8 and heights.max() < 1.0, heights
    lib = default_motion_lib()
    by_label = {}
    for mode in ("first_skill", "prop_free", "all"):
        cfg = resolve(TASKS / "carry.yaml", "mlp", [f"env.init_clips={mode}"])
        probs = start_clip_probs(lib, start_clip_labels(cfg))
        by_label[mode] = {c.skill: 0.0 for c in lib.clips}
        for c, p in zip(lib.clips, probs.tolist()):
            by_label[mode][c.skill] += p
    # Carry's own clips and walking only; every prop-free label alike; every label alike
    assert by_label["first_skill"] == pytest.approx({"carry": 0.5, "walk": 0.5, "idle": 0, "turn": 0,
                                                     "step_up": 0, "sit": 0})
    assert by_label["prop_free"] == pytest.approx({"carry": 0.25, "walk": 0.25, "idle": 0.25, "turn": 0.25,
                                                   "step_up": 0, "sit": 0})
    assert by_label["all"] == pytest.approx({label: 1 / 6 for label in by_label["all"]})


def test_no_clip_to_start_from_is_a_clear_error():
    lib = default_motion_lib()
    with pytest.raises(ValueError, match="no clip labelled"):
        reset_reference_sampler(lib, ("step_up",))  # every step-up clip stands on its step


def test_label_weights_leave_idle_out_of_starts_and_style_windows():
    from detach.skills import skill_class
    from detach.train.motion_bridge import motion_label_weights
    from detach.train.run_config import resolve_run

    cfg = resolve_run(TASKS / "follow.yaml", "mlp", ["train.amp.label_weights={idle: 0}"])
    lib = default_motion_lib(skill_weights=motion_label_weights(cfg))
    probs = lib.clip_probs(skill_class("follow").motion_labels)
    idle = torch.tensor([c.skill == "idle" for c in lib.clips])
    assert probs[idle].sum() == 0 and probs[~idle].sum() == pytest.approx(1.0)
    default = default_motion_lib().clip_probs(skill_class("follow").motion_labels)
    assert default[idle].sum() == pytest.approx(1 / 3)  # uniform over walk, turn and idle


def test_an_unknown_motion_label_is_a_config_error():
    from detach.config import ConfigError
    from detach.train.run_config import resolve_run

    with pytest.raises(ConfigError, match="label_weights.*expected a motion label"):
        resolve_run(TASKS / "follow.yaml", "mlp", ["train.amp.label_weights={jog: 0}"])
