"""Why do LH1 trials fail where they fail? 100 trials in 100 envs of the evaluation's config
(mean actions; not the evaluator's own trials, which its 16 envs play a few at a time), each
env's first episode followed step by step: its subtask scores, which termination ended it, the
step each subtask began, and for Sit the closest the pelvis came to the sit point (3-D and XY),
its height above it, its XY offset from it and the root's yaw there. Rows grouped by the pattern
of subtask scores.

    python results/laptop/diagnosis/lh1_trial_outcomes.py RUN_DIR CHECKPOINT.pt
"""
import collections
import math
import sys
from statistics import median_high as median
from pathlib import Path

import torch

from detach import RunFolder, eval_config, load_policy, make_env, seed_everything, yaw_of

run = RunFolder(Path(sys.argv[1]))
cfg = eval_config(run.config(), Path("configs/tasks/lh1.yaml"))
seed_everything(int(cfg.seed))
n = 100  # one trial per env: every first episode is followed
env = make_env(cfg, num_envs=n, device="cpu", eval_mode=True, verbose=False)
actor, _ = load_policy(cfg, env, Path(sys.argv[2]))
sit = list(cfg.task.plan).index("sit")
obs = env.get_observations()
live = torch.ones(n, dtype=torch.bool)
begin = torch.full((n, len(env.plan)), -1)
best = torch.full((n,), float("inf"))
best_off = torch.zeros(n, 3)  # pelvis - sit point where the pelvis came closest
best_yaw = torch.zeros(n)
rows = [None] * n
with torch.inference_mode():
    for t in range(env.max_episode_length + 5):
        ctx = env.context()
        sub = ctx.subtask.clone()
        for k in range(len(env.plan)):
            begin[:, k] = torch.where(live & (sub == k) & (begin[:, k] < 0), t, begin[:, k])
        at_sit = live & (sub == sit)
        d = ctx.dist
        closer = at_sit & (d < best)
        best = torch.where(closer, d, best)
        best_off = torch.where(closer[:, None], ctx.state.root_pos - ctx.target, best_off)
        best_yaw = torch.where(closer, yaw_of(ctx.state.root_quat), best_yaw)
        obs, _, dones, extras = env.step(actor(obs))
        prog = extras.get("episode_progress")
        for i in (dones & live).nonzero().flatten().tolist():
            ended = [k for k in env.terminations.names if bool(prog[k][i])]
            rows[i] = (tuple(prog["score"][i].float().tolist()), ",".join(ended) or "timeout/last", t + 1,
                       begin[i].tolist(), float(best[i]), float(best_off[i, :2].norm()), float(best_off[i, 2]),
                       best_off[i, :2].tolist(), math.degrees(float(best_yaw[i])))
            live[i] = False
        if not live.any():
            break

groups = collections.defaultdict(list)
for r in rows:
    if r is not None:
        groups[r[0]].append(r)
for scores, rs in sorted(groups.items(), key=lambda kv: -len(kv[1])):
    ends = collections.Counter(r[1] for r in rs)
    sit_start = [r[3][sit] for r in rs if r[3][sit] >= 0]
    ss = f"sit begins at step {median(sit_start)} (median)" if sit_start else ""
    near = [r for r in rs if r[4] < float("inf")]
    dd = (f"; closest to the sit point: 3-D {median(r[4] for r in near):.2f} m, XY "
          f"{median(r[5] for r in near):.2f} m, height {median(r[6] for r in near):+.2f} m" if near else "")
    print(f"{scores}: {len(rs)} trials; ended by {dict(ends)}; length median "
          f"{median(r[2] for r in rs)}; {ss}{dd}")
    for r in rs[:8] if near else ():
        print(f"    len {r[2]} begins {r[3]} sit closest 3-D {r[4]:.2f} XY {r[5]:.2f} dz {r[6]:+.2f} "
              f"(pelvis - sit point XY {r[7][0]:+.2f}, {r[7][1]:+.2f}; yaw {r[8]:+.0f} deg; {r[1]})")
