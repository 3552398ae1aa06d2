"""What a subtask's transition costs in reward: the scripted puppet oracle through LH1 (training
mode, 60-step holds, one env, power penalty off), the mean step reward per subtask, in its first
and last 10 steps. A policy that finishes Follow trades its end point's reward for Carry's early
one; where the first is larger, lingering outside the success distance pays.

    python results/laptop/diagnosis/oracle_reward_by_subtask.py [override ...]
"""
import sys

import torch

from detach import Oracle, make_env, resolve

torch.set_num_threads(1)
cfg = resolve("configs/tasks/lh1.yaml", "mlp", ["env.character=puppet", "rewards.power_coeff=0", *sys.argv[1:]],
              seed=1)
env = make_env(cfg, num_envs=1, verbose=False)
oracle = Oracle(env)
rewards: dict[int, list[float]] = {}
for _ in range(env.max_episode_length):
    sub = int(env.tracker.subtask[0])
    _obs, rew, dones, _extras = env.step(oracle())
    rewards.setdefault(sub, []).append(float(rew[0]))
    if bool(dones[0]):
        break
for sub, rs in sorted(rewards.items()):
    r = torch.tensor(rs)
    print(f"subtask {sub} ({env.plan[sub].skill}): {len(rs)} steps, mean {r.mean():.3f}, "
          f"first 10 {r[:10].mean():.3f}, last 10 {r[-10:].mean():.3f}")
