"""Where does a Carry policy go? Median root-to-box XY distance, the share of envs within 0.6 m,
the hands' median distance to the box surface, the share asking to grasp, the mean forward
action, and the shares with the box lifted and delivered (within 0.5 m of the destination),
every 60 control steps of 8 s (16 envs, mean actions), per checkpoint.

    python results/laptop/diagnosis/carry_rollout.py RUN_DIR CHECKPOINT.pt [CHECKPOINT.pt ...]
"""
import sys
import torch
from pathlib import Path
from eval_rollout import eval_env_and_policy
from detach import HAND_IDS, box_lifted, point_box_distance

for name in sys.argv[2:]:
    _run, _cfg, env, actor = eval_env_and_policy(sys.argv[1], name, 16)
    obs = env.get_observations()
    rows = []
    with torch.no_grad():
        for t in range(240):
            a = actor(obs)
            obs, *_ = env.step(a)
            if t % 30 == 29:
                ctx = env.context()
                d = (ctx.obj_pos[:, :2] - ctx.state.root_pos[:, :2]).norm(dim=-1)
                hands = ctx.state.body_pos[:, HAND_IDS]
                h = point_box_distance(hands, ctx.obj_pos[:, None], ctx.obj_quat[:, None],
                                       ctx.obj_half[:, None]).mean(-1)
                home = (ctx.obj_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1) < 0.5
                rows.append((t + 1, d.median().item(), (d < 0.6).float().mean().item(), h.median().item(),
                             (a[:, -1] > 0).float().mean().item(), a[:, 32].mean().item(),
                             box_lifted(ctx).float().mean().item(), home.float().mean().item()))
    print(Path(name).name, " ".join(f"t{t}: box {dm:.2f}m near {nf:.2f} hands {hm:.2f} grasp>0 {g:.2f} fwd {f:+.2f} "
                                    f"lifted {lf:.2f} home {hf:.2f}" for t, dm, nf, hm, g, f, lf, hf in rows[::2]))
