"""A skill is a plug-in: `reach` (touch a target point with a hand), defined in this file alone,
runs through a task YAML, the environment, a scripted policy, the evaluator with its column in
the tables, and the dashboard's scene message, without touching any other module."""

from __future__ import annotations

import textwrap
from pathlib import Path

import numpy as np
import pytest
import torch

from detach.character.body import BODY_NAMES
from detach.config import resolve
from detach.envs.lh_env import make_env
from detach.envs.oracle import Oracle
from detach.eval.episodes import run_evaluation
from detach.eval.scene import scene_message
from detach.eval.tables import skills_table
from detach.runfolder.eval_result import EvalResult
from detach.runfolder.messages import SceneMessage
from detach.skills import RewardTerm, Skill, register_skill, skill_names, unregister_skill
from detach.skills.context import OracleCommand, SkillContext
from detach.train.run_config import resolve_run

RIGHT_HAND = BODY_NAMES.index("right_hand")


def hand_close(ctx: SkillContext) -> torch.Tensor:
    return torch.exp(-10.0 * ctx.dist ** 2)


class Reach(Skill):
    """Touch a fixed point (`tarpos_K`) with the right hand: done when the hand holds within
    `success_threshold` of it for the transition time."""

    name = "reach"
    display_name = "Reach"
    color = (200, 30, 160)
    motion_labels = ("idle",)
    sources = ("tarpos",)
    reward_terms = {"hand_close": RewardTerm(hand_close, 1.0)}

    def distance(self, ctx: SkillContext) -> torch.Tensor:
        return (ctx.state.body_pos[:, RIGHT_HAND] - ctx.target).norm(dim=-1)

    def oracle(self, ctx: SkillContext, cmd: OracleCommand, active: torch.Tensor) -> None:
        """Move the pelvis so that the hand comes onto the point, then hold."""
        hand = ctx.state.body_pos[:, RIGHT_HAND]
        v = (2.5 * (ctx.target[:, :2] - hand[:, :2])).clamp(-1.2, 1.2)
        cmd.velocity = torch.where(active[:, None], v, cmd.velocity)
        cmd.yaw_target = torch.where(active, torch.zeros_like(cmd.yaw_target), cmd.yaw_target)
        height = ctx.state.root_pos[:, 2] + (ctx.target[:, 2] - hand[:, 2])
        cmd.height = torch.where(active, height, cmd.height)


@pytest.fixture()
def reach_task(tmp_path: Path):
    register_skill(Reach)
    task = tmp_path / "reach.yaml"
    base = Path(__file__).resolve().parents[1] / "configs" / "tasks" / "base" / "defaults.yaml"
    task.write_text(textwrap.dedent(f"""\
        extends: {base}
        name: reach
        humanoid: {{init_pos2d: [0.0, 0.0], init_rot_randomize: false}}
        target_positions: [[1.5, -0.2, 0.4]]
        plan: [reach]
        target_object: [0]
        sample_target_from: [tarpos_0]
        env: {{episode_length: 300}}
        """))
    yield task
    unregister_skill("reach")


def test_a_skill_defined_in_a_test_runs_end_to_end(reach_task: Path) -> None:
    assert skill_names()[-1] == "reach" and skill_names()[:4] == ("follow", "carry", "climb", "sit")
    cfg = resolve_run(reach_task, "mlp", ["env.character=puppet"])
    env = make_env(cfg, num_envs=2, eval_mode=True, verbose=False)
    assert env.obs_spec.num_skills == 5 and env.get_observations()["task"][0].tolist() == [0, 0, 0, 0, 1]
    assert "reach/hand_close" in env.rewards.active

    oracle = Oracle(env)
    result = run_evaluation(env, lambda _obs: oracle(), trials=4, cfg=cfg, progress=False)
    assert result.plan == ["reach"] and result.subtasks[0].rate == 1.0, result
    assert result.lh_success.rate == 1.0

    parsed = EvalResult.from_json(result.to_json())
    table = skills_table([parsed], task="reach")
    assert table.header[:6] == ["Method", "Follow", "Carry", "Climb", "Sit", "Reach"]
    assert table.rows[0][5].value == 1.0

    scene = SceneMessage.from_json(scene_message(env, cfg).to_json())
    assert [(t.skill, t.color) for t in scene.targets] == [("reach", [200, 30, 160])]
    assert np.allclose(scene.targets[0].pos, [1.5, -0.2, 0.4])


def test_a_random_policy_does_not_reach(reach_task: Path) -> None:
    cfg = resolve(reach_task, "mlp", ["env.character=puppet"])
    env = make_env(cfg, num_envs=2, eval_mode=True, verbose=False)
    gen = torch.Generator().manual_seed(0)
    result = run_evaluation(env, lambda _obs: torch.rand(2, env.num_actions, generator=gen) * 2 - 1,
                            trials=2, cfg=cfg, progress=False)
    assert result.subtasks[0].rate == 0.0


def test_an_unknown_skill_in_a_task_names_file_line_and_the_skills(tmp_path: Path) -> None:
    from detach.config import ConfigError

    task = tmp_path / "bad.yaml"
    base = Path(__file__).resolve().parents[1] / "configs" / "tasks" / "follow.yaml"
    task.write_text(f"extends: {base}\nplan: [reach]\n")
    with pytest.raises(ConfigError, match=r"bad.yaml:2: plan\[0\]: unknown skill 'reach'; available: follow"):
        resolve_run(task, "mlp")
