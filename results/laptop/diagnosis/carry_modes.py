"""Does a Carry policy fail under mean actions where its sampled actions succeed? Runs the
evaluation (default starts, the run's evaluation settings) of each checkpoint twice, with mean
and with sampled actions, and prints per mode the Carry success, the shares delivered / grasped
only, and the grasp action's mean while both hands are within 0.12 m of the box (where a grasp
request is granted) and the box is not lifted; of those steps, the share where the character
already holds the box (welded, not lifted), the box's height above its rest and the pelvis
height action's mean.

    python results/laptop/diagnosis/carry_modes.py RUN_DIR TRIALS CHECKPOINT.pt [CHECKPOINT.pt ...]

MODES=mean (environment variable) runs only the mean-action evaluation.
"""
import os
import sys
from pathlib import Path

import torch

from detach import (
    HAND_IDS, RunFolder, box_lifted, eval_config, load_policy, make_env, point_box_distance, run_evaluation,
    seed_everything,
)

run = RunFolder(Path(sys.argv[1]))
trials = int(sys.argv[2])
cfg = eval_config(run.config(), None)
for name in sys.argv[3:]:
    for mode in os.environ.get("MODES", "mean,sampled").split(","):
        seed_everything(1)
        env = make_env(cfg, num_envs=cfg.eval.num_envs, device="cpu", eval_mode=True)
        actor, _ = load_policy(cfg, env, Path(name))
        near_grasp: list[torch.Tensor] = []
        near_held: list[torch.Tensor] = []
        near_rise: list[torch.Tensor] = []
        near_height: list[torch.Tensor] = []

        def policy(obs, actor=actor, env=env, mode=mode, near_grasp=near_grasp):
            a = actor(obs, stochastic_output=mode == "sampled")
            ctx = env.context()
            hands = ctx.state.body_pos[:, HAND_IDS]
            d = point_box_distance(hands, ctx.obj_pos[:, None], ctx.obj_quat[:, None], ctx.obj_half[:, None])
            near = (d < 0.12).all(-1) & ~box_lifted(ctx)
            near_grasp.append(a[near, -1])
            near_held.append(env.character.held_object()[near] >= 0)
            near_rise.append((ctx.obj_pos[:, 2] - ctx.obj_rest_z)[near])
            near_height.append(a[near, -2])
            return a

        res = run_evaluation(env, policy, trials, cfg, progress=False)
        scores = torch.tensor([t[0] for t in res.trial_scores])
        g = torch.cat(near_grasp) if near_grasp else torch.zeros(0)
        sub = res.subtasks[0]
        print(f"{Path(name).name} {mode}: carry {sub.rate:.2f} [{sub.ci[0]:.2f}, {sub.ci[1]:.2f}] "
              f"delivered {(scores == 1).float().mean().item():.2f} grasped only "
              f"{(scores == 0.5).float().mean().item():.2f}", flush=True)
        print(f"  grasp action near the box: n={len(g)} mean={g.mean().item() if len(g) else float('nan'):+.3f} "
              f"share>0={(g > 0).float().mean().item() if len(g) else float('nan'):.2f}", flush=True)
        if len(g):
            held, rise, height = torch.cat(near_held).float(), torch.cat(near_rise), torch.cat(near_height)
            print(f"  of those steps: held (welded) {held.mean().item():.2f}, box above rest median "
                  f"{rise.median().item():+.3f} m, height action mean {height.mean().item():+.3f} "
                  f"(held: {height[held > 0].mean().item() if held.any() else float('nan'):+.3f})", flush=True)
