"""Add a skill

A skill is one `Skill` subclass registered with `register_skill`: how a plan entry is targeted,
its distance, reward terms, success, scripted oracle and display colour. Tasks name it in their
plan; the environment, the evaluator, the tables and the dashboard pick it up. Here: `reach`,
touch a point with the right hand, solved by the scripted oracle.

    python examples/04_add_skill.py
"""

import tempfile
import textwrap
from pathlib import Path

import torch

from detach import (
    BODY_NAMES, Oracle, OracleCommand, RewardTerm, Skill, SkillContext, builtin_configs, make_env, register_skill,
    resolve_run, run_evaluation, unregister_skill,
)

RIGHT_HAND = BODY_NAMES.index("right_hand")


class Reach(Skill):
    name = "reach"
    display_name = "Reach"
    color = (200, 30, 160)
    motion_labels = ("idle",)
    sources = ("tarpos",)
    reward_terms = {"hand_close": RewardTerm(lambda ctx: torch.exp(-10.0 * ctx.dist ** 2), 1.0)}

    def distance(self, ctx: SkillContext) -> torch.Tensor:
        return (ctx.state.body_pos[:, RIGHT_HAND] - ctx.target).norm(dim=-1)

    def oracle(self, ctx: SkillContext, cmd: OracleCommand, active: torch.Tensor) -> None:
        hand = ctx.state.body_pos[:, RIGHT_HAND]
        v = (2.5 * (ctx.target[:, :2] - hand[:, :2])).clamp(-1.2, 1.2)
        cmd.velocity = torch.where(active[:, None], v, cmd.velocity)
        cmd.yaw_target = torch.where(active, torch.zeros_like(cmd.yaw_target), cmd.yaw_target)
        cmd.height = torch.where(active, ctx.state.root_pos[:, 2] + (ctx.target[:, 2] - hand[:, 2]), cmd.height)


def main() -> None:
    register_skill(Reach)
    try:
        with tempfile.TemporaryDirectory() as tmp:
            task = Path(tmp) / "reach.yaml"
            task.write_text(textwrap.dedent(f"""\
                extends: {builtin_configs() / "tasks/base/defaults.yaml"}
                name: reach
                humanoid: {{init_pos2d: [0.0, 0.0], init_rot_randomize: false}}
                target_positions: [[1.5, -0.2, 0.4]]
                plan: [reach]
                target_object: [0]
                sample_target_from: [tarpos_0]
                env: {{episode_length: 300}}
                """))
            cfg = resolve_run(task, "mlp", ["env.character=puppet"])
            env = make_env(cfg, num_envs=2, eval_mode=True)
            oracle = Oracle(env)
            result = run_evaluation(env, lambda _obs: oracle(), trials=2, cfg=cfg, progress=False)
            print(f"reach success with the scripted oracle: {result.subtasks[0].rate:.2f}")
    finally:
        unregister_skill("reach")


if __name__ == "__main__":
    main()
