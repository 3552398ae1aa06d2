"""Untrained vs trained policy of one run, side by side: episode length and AMP style reward.

    python benchmarks/style_gain.py runs/<run> [--checkpoint PATH] [--envs 16] [--steps 900]

Both policies act (mean actions) in the run's own env for the same number of steps from the
same seed; the untrained one is the run's model freshly initialised with the run's seed (what
iteration 0 acted with). Style rewards of both are scored by the *trained* checkpoint's
discriminator, so the two numbers are on one scale (the reward logged during training is
scored by a discriminator that changes as it learns). Episode length is the mean over the
episodes that ended in the window, with episodes still running at its end counted at their
length so far (a lower bound).
"""

from __future__ import annotations

import argparse
import dataclasses
import statistics
from pathlib import Path

import torch

from detach import RunFolder, build_runner


def rollout(env, policy, scorer, steps: int) -> dict[str, float]:
    obs = env.get_observations()
    length = torch.zeros(env.num_envs)
    lengths: list[float] = []
    style, task = [], []
    with torch.inference_mode():
        for _ in range(steps):
            cond = obs["task"]
            obs, rew, dones, extras = env.step(policy(obs))
            amp = obs["amp"]
            terminal = extras.get("terminal_amp")
            if terminal is not None:
                amp = torch.where(dones.reshape(-1, 1).bool(), terminal, amp)
            style.append(float(scorer(amp, cond).mean()))
            task.append(float(rew.mean()))
            length += 1
            ended = dones.reshape(-1).nonzero().flatten()
            lengths += length[ended].tolist()
            length[ended] = 0
    running = length[length > 0].tolist()
    return {"episode_length": statistics.fmean(lengths + running), "episodes_ended": len(lengths),
            "style_reward": statistics.fmean(style), "task_reward": statistics.fmean(task)}


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("run", type=Path)
    ap.add_argument("--checkpoint", type=Path, default=None, help="default: the run's latest")
    ap.add_argument("--envs", type=int, default=16)
    ap.add_argument("--steps", type=int, default=900)
    args = ap.parse_args()
    run = RunFolder(args.run)
    cfg = run.config()
    cfg = dataclasses.replace(cfg, sim=dataclasses.replace(cfg.sim, num_envs=args.envs))
    checkpoint = args.checkpoint or run.latest_checkpoint()
    # Same seed for both: the same initial weights (untrained) and the same env resets.
    env_u, untrained = build_runner(cfg, None, "cpu", progress=False)
    env_t, trained = build_runner(cfg, None, "cpu", progress=False)
    trained.load(str(checkpoint))
    scorer = trained.alg._style_rewards
    results = {}
    for name, env, runner in (("untrained", env_u, untrained), ("trained", env_t, trained)):
        actor = runner.alg.actor
        actor.eval()
        results[name] = rollout(env, lambda o, a=actor: a(o), scorer, args.steps)
    print(f"run {run.path.name}, checkpoint {checkpoint.name}, {args.envs} envs x {args.steps} steps, "
          "mean actions, style scored by the checkpoint's discriminator")
    print("| policy | episode length (steps) | episodes ended | style reward / step | task reward / step |")
    print("| --- | --- | --- | --- | --- |")
    for name, r in results.items():
        print(f"| {name} | {r['episode_length']:.1f} | {r['episodes_ended']} | {r['style_reward']:.3f} | "
              f"{r['task_reward']:.3f} |")


if __name__ == "__main__":
    main()
