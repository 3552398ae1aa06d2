"""Where does a Carry policy take the box once it holds it? Runs the evaluation's default starts
(48 envs, mean actions) for 400 control steps (13 s) and prints, over the envs still holding the
box then (a delivered box ends its episode, so these are the deliveries that have not
happened), quartiles of the pelvis's distance to the place it is shown to walk to
(`Carry.goal`), of the box's 3-D distance to its destination (success: under
`env.success_threshold`), of the box's height above the destination, and of the pelvis's speed.

    python results/laptop/diagnosis/carry_after_grasp.py RUN_DIR CHECKPOINT.pt
"""
import sys
from pathlib import Path

import torch

from detach.envs.lh_env import make_env
from detach.runs.folder import RunFolder
from detach.runs.policy import load_policy
from detach.runs.session import eval_config
from detach.train.setup import seed_everything

ENVS, STEPS = 48, 400

run = RunFolder(Path(sys.argv[1]))
cfg = eval_config(run.config(), None)
seed_everything(1)
env = make_env(cfg, num_envs=ENVS, device="cpu", eval_mode=True)
actor, _ = load_policy(cfg, env, Path(sys.argv[2]))
obs = env.get_observations()
with torch.no_grad():
    for _ in range(STEPS):
        obs, *_ = env.step(actor(obs))
ctx = env.context()
held = env.character.grasp_obj >= 0


def quartiles(x: torch.Tensor) -> str:
    return " / ".join(f"{v:.2f}" for v in torch.quantile(x, torch.tensor([0.25, 0.5, 0.75])).tolist())


print(f"{Path(sys.argv[2]).name} of {run.path.name}: holding at {STEPS * env.dt:.1f} s: {held.float().mean():.2f}; "
      f"pelvis to goal (m) {quartiles((ctx.state.root_pos[held, :2] - ctx.goal[held, :2]).norm(dim=-1))}; "
      f"box to destination (m) {quartiles((ctx.obj_pos[held] - ctx.target[held]).norm(dim=-1))}; "
      f"box above destination (m) {quartiles(ctx.obj_pos[held, 2] - ctx.target[held, 2])}; "
      f"pelvis speed (m/s) {quartiles(ctx.state.body_lin[held, 0, :2].norm(dim=-1))}; "
      f"success threshold {cfg.env.success_threshold} m")
