"""How does a Carry policy stand at the box before it grasps? Over the evaluation's default
starts (48 envs, 8 s, mean actions), every 5 control steps where the pelvis is within 0.6 m
(XY) of the box and nothing is held: the heading's angle to the box, the farther hand's
distance to the box's surface (a grasp needs both within 0.12 m) and the pelvis-to-box
distance, as quartiles; and the share of envs that have grasped the box by 2, 5 and 10 s (an
evaluation episode lasts 20 s, and the delivery comes after the grasp).

    python results/laptop/diagnosis/carry_approach.py RUN_DIR CHECKPOINT.pt
"""
import math
import sys
from pathlib import Path

import torch
from eval_rollout import eval_env_and_policy, quartiles

from detach import HAND_IDS, point_box_distance, wrap_angle, yaw_of

ENVS, STEPS, NEAR_BOX = 48, 300, 0.6

run, cfg, env, actor = eval_env_and_policy(sys.argv[1], sys.argv[2], ENVS)
obs = env.get_observations()
yaw_err, hand_d, pelvis_d = [], [], []
reached = torch.zeros(ENVS, dtype=torch.bool)
first_grasp = torch.full((ENVS,), -1)
with torch.no_grad():
    for t in range(STEPS):
        obs, *_ = env.step(actor(obs))
        ctx = env.context()
        rel = ctx.obj_pos[:, :2] - ctx.state.root_pos[:, :2]
        d = rel.norm(dim=-1)
        at = (d < NEAR_BOX) & (env.character.grasp_obj < 0)
        reached |= d < NEAR_BOX
        first_grasp = torch.where((env.character.grasp_obj >= 0) & (first_grasp < 0), t, first_grasp)
        if t % 5 == 4 and bool(at.any()):
            e = wrap_angle(torch.atan2(rel[:, 1], rel[:, 0]) - yaw_of(ctx.state.root_quat)).abs()
            h = point_box_distance(ctx.state.body_pos[:, HAND_IDS], ctx.obj_pos[:, None], ctx.obj_quat[:, None],
                                   ctx.obj_half[:, None]).max(-1).values
            yaw_err.append(e[at])
            hand_d.append(h[at])
            pelvis_d.append(d[at])
ye, hd, pd = torch.cat(yaw_err) * 180 / math.pi, torch.cat(hand_d), torch.cat(pelvis_d)


print(f"{Path(sys.argv[2]).name} of {run.path.name}: {len(ye)} samples at the box, nothing held; "
      f"heading to box (deg) {quartiles(ye)}; farther hand to box (m) {quartiles(hd)}; "
      f"pelvis to box (m) {quartiles(pd)}; share with both hands within 0.12 m {(hd < 0.12).float().mean():.2f}; "
      f"envs that reached the box {reached.float().mean():.2f}; grasped by 2 / 5 / 10 s "
      + " / ".join(f"{((first_grasp >= 0) & (first_grasp < s / env.dt)).float().mean():.2f}" for s in (2, 5, 10)))
