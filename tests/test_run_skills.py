"""A run's skills are part of its config (`env.skills`, config.yaml), not of the process: a
skill registered by a plug-in changes neither the observation sizes of a run that does not
list it nor whether an earlier checkpoint fits (the `task` one-hot once had one entry per
registered skill, so importing an add-on skill broke every earlier checkpoint)."""

from __future__ import annotations

import os
from pathlib import Path

import pytest
import yaml

from detach.config import load_run_config
from detach.envs.lh_env import make_env
from detach.skills import DEFAULT_RUN_SKILLS, register_skill, run_skills, skill_names, unregister_skill
from detach.train.run_config import resolve_run
from detach.train.setup import build_runner, load_initial_weights
from tests.test_skill_plugin import Reach

ROOT = Path(__file__).resolve().parents[1]
OLD_RUN = ROOT / "results/laptop/cells/20261203-014524-follow-detach-s0"
"""A run folder recorded before env.skills existed (DETACH on the puppet's Follow)."""


@pytest.fixture()
def reach_registered():
    register_skill(Reach)
    yield
    unregister_skill("reach")


def test_an_add_on_skill_leaves_a_new_runs_observation_size_alone(reach_registered: None) -> None:
    assert "reach" in skill_names()
    cfg = resolve_run(ROOT / "configs/tasks/follow.yaml", "mlp", ["env.character=puppet"])
    assert cfg.env.skills == DEFAULT_RUN_SKILLS == ("follow", "carry", "climb", "sit")
    env = make_env(cfg, num_envs=2, eval_mode=True, verbose=False)
    assert env.obs_spec.num_skills == 4 and env.obs_spec.skills == DEFAULT_RUN_SKILLS
    assert env.get_observations()["task"].shape == (2, 4)


def test_a_run_recorded_without_the_key_keeps_its_sizes_and_its_checkpoint_fits(
        reach_registered: None, monkeypatch: pytest.MonkeyPatch) -> None:
    recorded = yaml.safe_load((OLD_RUN / "config.yaml").read_text())
    assert "skills" not in recorded["env"]
    cfg = load_run_config(OLD_RUN / "config.yaml", ["sim.num_envs=2"])
    assert cfg.env.skills == ()
    env = make_env(cfg, num_envs=2, eval_mode=True, verbose=False)
    assert env.skills == DEFAULT_RUN_SKILLS and env.obs_spec.num_skills == 4

    monkeypatch.chdir(ROOT)  # the shipped policy of pretrained/, trained before the key, loads
    cfg = resolve_run(ROOT / "configs/tasks/follow.yaml", "detach", ["sim.num_envs=2"],
                      presets=["first_run"])
    assert cfg.env.skills == DEFAULT_RUN_SKILLS and os.path.isfile(cfg.train.init_from)
    _env, runner = build_runner(cfg, None, "cpu", progress=False)
    assert "model detach (detach), iteration 399" in load_initial_weights(runner, cfg)


def test_a_listed_skill_list_orders_the_one_hot(reach_registered: None) -> None:
    assert run_skills((), ["reach", "follow"]) == (*DEFAULT_RUN_SKILLS, "reach")
    assert run_skills(["reach", "traj"], ["follow"]) == ("reach", "follow")
    with pytest.raises(ValueError, match="the plan uses carry, which the list"):
        run_skills(["follow"], ["follow", "carry"])
    task = ROOT / "configs/tasks/follow.yaml"
    cfg = resolve_run(task, "mlp", ["env.character=puppet", "env.skills=[reach,follow]"])
    env = make_env(cfg, num_envs=2, eval_mode=True, verbose=False)
    assert env.obs_spec.num_skills == 2 and env.get_observations()["task"][0].tolist() == [0, 1]


def test_an_unknown_skill_in_the_list_names_the_key() -> None:
    from detach.config import ConfigError

    with pytest.raises(ConfigError, match=r"env\.skills: unknown skill 'jump'"):
        resolve_run(ROOT / "configs/tasks/follow.yaml", "mlp", ["env.skills=[follow,jump]"])
