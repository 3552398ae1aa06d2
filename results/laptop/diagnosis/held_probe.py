"""Held starts under a checkpoint's policy with exploration noise (32 envs, every start
mid-task): how many boxes are still held, the grasp action's mean and minimum, and the logged
box_to_target reward, every 15 control steps.

    python results/laptop/diagnosis/held_probe.py RUN_DIR CHECKPOINT.pt [STD (default 0.3)]
"""
import sys
from dataclasses import replace
from pathlib import Path

import torch

from detach import GRASP_ACTION, RunFolder, load_policy, make_env


def main() -> None:
    cfg = RunFolder(Path(sys.argv[1])).config()
    cfg = replace(cfg, env=replace(cfg.env, mid_task_init_prob=1.0))
    std = float(sys.argv[3]) if len(sys.argv) > 3 else 0.3
    torch.manual_seed(0)
    env = make_env(cfg, num_envs=32, device="cpu", verbose=False)
    actor, _ = load_policy(cfg, env, Path(sys.argv[2]))
    obs = env.get_observations()
    held0 = env.character.held_object() >= 0
    print("held at start", int(held0.sum()), "of", env.num_envs)
    with torch.no_grad():
        for t in range(150):
            mean = actor(obs)
            a = mean + std * torch.randn_like(mean)
            obs, _rew, dones, extras = env.step(a)
            held = env.character.held_object() >= 0
            if t % 15 == 0:
                paid = float(extras["log"].get("Episode_Reward/carry/box_to_target", torch.tensor(0.0)))
                print(t, "held", int((held & held0).sum()), "grasp mean",
                      round(float(mean[held0, GRASP_ACTION].mean()), 3), "min",
                      round(float(a[held0, GRASP_ACTION].min()), 2), "done", int(dones.sum()),
                      "box_to_target", round(paid, 3))


if __name__ == "__main__":
    main()
