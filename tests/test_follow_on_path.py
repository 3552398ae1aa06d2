"""Follow's opt-in `on_path` term: a kernel on the pelvis's distance to the path itself (the
success rule's measure), not to the moving reference point."""

from __future__ import annotations

from pathlib import Path

import torch

from detach.config import resolve
from detach.envs.lh_env import make_env

ROOT = Path(__file__).resolve().parents[1]


def _logged(overrides: list[str], steps: int) -> list[dict[str, float]]:
    cfg = resolve(ROOT / "configs/tasks/lh1.yaml", "mlp", ["env.character=puppet", *overrides], seed=1)
    env = make_env(cfg, num_envs=2, verbose=False)
    out = []
    for _ in range(steps):
        _obs, _rew, _dones, extras = env.step(torch.zeros(2, env.num_actions))
        out.append({k.removeprefix("Episode_Reward/"): float(v) for k, v in extras["log"].items()})
    return out


def test_standing_at_the_start_is_on_the_path_but_behind_the_reference() -> None:
    """Zero actions keep the puppet at LH1's path start: the reference walks away (position
    falls) while the pelvis stays on the path (on_path stays near 1)."""
    torch.set_num_threads(1)
    log = _logged(["+rewards.terms.follow/on_path=0.3"], 60)
    assert log[0]["follow/on_path"] > 0.9 and log[-1]["follow/on_path"] > 0.9
    assert log[-1]["follow/position"] < 0.5 * log[0]["follow/position"]


def test_the_term_is_off_by_default() -> None:
    log = _logged([], 2)
    assert "follow/on_path" not in log[-1] and "follow/position" in log[-1]
