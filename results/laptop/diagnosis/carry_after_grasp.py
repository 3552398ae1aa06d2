"""Where does a Carry policy take the box once it holds it? Runs the evaluation's default starts
(48 envs, mean actions) for 400 control steps (13 s), following each env's first episode only
(an episode ends when its box is delivered, and the env then starts another), and prints,
over the envs still in their first episode and holding the box at the end (the deliveries
that have not happened), quartiles of the pelvis's distance to the place it is shown to walk to
(`Carry.goal`), of the box's 3-D distance to its destination (success: under
`env.success_threshold`), of the box's height above the destination, and of the pelvis's speed;
and, over every step an env held the box more than 0.5 m from its goal in its first
episode, quartiles of the cosine
between the velocity the puppet's root actions ask for (actions 32-33, heading frame) and the
direction to the goal (1: walking the box straight to it).

    python results/laptop/diagnosis/carry_after_grasp.py RUN_DIR CHECKPOINT.pt
"""
import sys
from pathlib import Path

import torch
from eval_rollout import eval_env_and_policy, quartiles

from detach import yaw_of

ENVS, STEPS = 48, 400

run, cfg, env, actor = eval_env_and_policy(sys.argv[1], sys.argv[2], ENVS)
obs = env.get_observations()
aims = []
first = torch.ones(ENVS, dtype=torch.bool)
with torch.no_grad():
    for _ in range(STEPS):
        actions = actor(obs)
        ctx = env.context()
        to_goal = ctx.goal[:, :2] - ctx.state.root_pos[:, :2]
        yaw = yaw_of(ctx.state.root_quat)
        fwd, left = actions[:, 32], actions[:, 33]
        asked = torch.stack((fwd * yaw.cos() - left * yaw.sin(), fwd * yaw.sin() + left * yaw.cos()), -1)
        far = first & (env.character.grasp_obj >= 0) & (to_goal.norm(dim=-1) > 0.5)
        aims.append(torch.nn.functional.cosine_similarity(asked[far], to_goal[far], dim=-1))
        obs, _rewards, dones, _extras = env.step(actions)
        first &= ~dones.bool()
ctx = env.context()
held = first & (env.character.grasp_obj >= 0)


print(f"{Path(sys.argv[2]).name} of {run.path.name}: first episode ended by {STEPS * env.dt:.1f} s: "
      f"{(~first).float().mean():.2f}; still in it and holding: {held.float().mean():.2f}; "
      f"pelvis to goal (m) {quartiles((ctx.state.root_pos[held, :2] - ctx.goal[held, :2]).norm(dim=-1))}; "
      f"box to destination (m) {quartiles((ctx.obj_pos[held] - ctx.target[held]).norm(dim=-1))}; "
      f"box above destination (m) {quartiles(ctx.obj_pos[held, 2] - ctx.target[held, 2])}; "
      f"pelvis speed (m/s) {quartiles(ctx.state.body_lin[held, 0, :2].norm(dim=-1))}; "
      f"success threshold {cfg.env.success_threshold} m; asked velocity vs goal direction (cos), held and "
      f"> 0.5 m from it: {quartiles(torch.cat(aims))}")
