"""Where does a policy go in LH1's (or another task's) first Follow subtask? Every 30 control
steps (8 envs, mean actions): the median pelvis XY, its median distance to the path (the success
rule's 0.3 m) and to the moving reference point, the share of steps on the path so far, and the
share still in Follow.

    python results/laptop/diagnosis/lh1_follow_rollout.py RUN_DIR CHECKPOINT.pt [TASK, default lh1]
    python results/laptop/diagnosis/lh1_follow_rollout.py - POLICY.policy.pt [TASK]   (a shipped policy)
"""
import sys
from pathlib import Path

import torch

from detach import (RunFolder, distance_to_polyline, eval_config, load_policy, load_run_config, make_env,
                    seed_everything)

NUM_ENVS = 8

train_cfg = (load_run_config(Path(sys.argv[2].removesuffix(".pt") + ".yaml")) if sys.argv[1] == "-"
             else RunFolder(Path(sys.argv[1])).config())
cfg = eval_config(train_cfg, Path(f"configs/tasks/{sys.argv[3] if len(sys.argv) > 3 else 'lh1'}.yaml"))
seed_everything(1)
env = make_env(cfg, num_envs=NUM_ENVS, device="cpu", eval_mode=True)
actor, _ = load_policy(cfg, env, Path(sys.argv[2]))
obs = env.get_observations()
threshold = cfg.env.success_threshold  # the Follow success rule's distance to the path
on = torch.zeros(NUM_ENVS)
steps = torch.zeros(NUM_ENVS)
with torch.no_grad():
    for t in range(450):
        obs, *_ = env.step(actor(obs))
        ctx = env.context()
        xy = ctx.state.root_pos[:, :2]
        in_follow = ctx.subtask == 0
        d_path = distance_to_polyline(xy, env.services.trajectory.verts)
        on += (in_follow & (d_path <= threshold)).float()
        steps += in_follow.float()
        if t % 30 == 29:
            d_ref = (ctx.ref_xy - xy).norm(dim=-1)
            print(f"t{t + 1}: pelvis {xy.median(0).values.tolist()} path {d_path.median():.2f} m "
                  f"ref {d_ref.median():.2f} m on-path {(on / steps.clamp(min=1)).median():.2f} "
                  f"in follow {in_follow.float().mean():.2f}", flush=True)
