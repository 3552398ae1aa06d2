"""Which skills the discriminator's reference windows come from: the plan's, weighted by
`train.amp.skill_weights` (TokenHSI's skill-discrimination probabilities pooled per skill)."""

from __future__ import annotations

import pytest
import torch

from detach.motion import default_motion_lib
from detach.skills import skill_names
from detach.train.motion_bridge import amp_reference_sampler, skill_draw_weights

PAPER = {"follow": 0.1, "carry": 0.3, "climb": 0.3, "sit": 0.3}


def test_draw_weights_keep_the_plan_and_renormalise() -> None:
    every = ["follow", "carry", "climb", "sit"]
    assert skill_draw_weights(every, every, PAPER) == pytest.approx(PAPER)
    assert skill_draw_weights(["follow", "carry", "follow"], every, PAPER) == pytest.approx(
        {"follow": 0.25, "carry": 0.75})
    assert skill_draw_weights(["sit"], every, {}) == {"sit": 1.0}
    assert skill_draw_weights(["follow", "reach"], [*every, "reach"], PAPER) == pytest.approx(
        {"follow": 0.1 / 0.35, "reach": 0.25 / 0.35})
    assert skill_draw_weights(["reach"], every, {}) == pytest.approx({s: 0.25 for s in every})  # no clips of its own
    with pytest.raises(ValueError, match="weight 0"):
        skill_draw_weights(["follow"], every, {"follow": 0.0})


def test_reference_windows_follow_the_weights() -> None:
    torch.manual_seed(0)
    sample = amp_reference_sampler(default_motion_lib(), steps=2, dt=1 / 30, plan=["follow", "carry"], weights=PAPER)
    windows, onehot = sample(2000)
    assert windows.shape[0] == 2000 and torch.isfinite(windows).all()
    share = onehot.mean(0)
    names = skill_names()
    assert share[names.index("carry")] == pytest.approx(0.75, abs=0.04)
    assert share[names.index("follow")] == pytest.approx(0.25, abs=0.04)
    assert share[names.index("climb")] == share[names.index("sit")] == 0.0
