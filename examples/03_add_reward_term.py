"""Add a reward term

A skill's reward terms are functions of the `SkillContext` (the simulation state of every env,
its target and distance) with a default weight; the config sets any weight as
`rewards.terms.<skill>/<term>`. Here: an `upright` term for the follow skill.

    python examples/03_add_reward_term.py
"""

import torch

from detach import RewardTerm, SkillContext, find_task_file, make_env, resolve_run, skill_class


def upright(ctx: SkillContext) -> torch.Tensor:
    """1 when the root's z axis points up, 0 when it lies flat (in [0, 1] by convention)."""
    w, x, y, _z = ctx.state.root_quat.unbind(-1)
    up_z = 1 - 2 * (x * x + y * y)  # z component of the rotated z axis
    return up_z.clamp(min=0)


def main() -> None:
    follow = skill_class("follow")
    follow.reward_terms = {**follow.reward_terms, "upright": RewardTerm(upright, 0.1)}
    try:
        cfg = resolve_run(find_task_file("follow"), "mlp",
                          ["env.character=puppet", "+rewards.terms.follow/upright=0.2"])
        env = make_env(cfg, num_envs=2, eval_mode=True)
        assert "follow/upright" in env.rewards.active
        _obs, reward, _dones, _extras = env.step(torch.zeros(env.num_envs, env.num_actions))
        print(f"active terms: {sorted(env.rewards.active)}; reward after one step {reward.tolist()}")
    finally:
        follow.reward_terms = {k: v for k, v in follow.reward_terms.items() if k != "upright"}


if __name__ == "__main__":
    main()
