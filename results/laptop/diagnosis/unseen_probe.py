"""Does the Follow policy walk to Carry's box, and why? Median pelvis-to-box distance and mean
forward action of a policy checkpoint in the Carry scene (16 envs, mean actions, 5 s), with its
observation statistics: `keep` (the checkpoint's own: inputs the source never varied are divided
by rsl-rl's eps), `merge0` (`train.init_normalizers: merge` before any update: those inputs read
as the constant the policy knew) and `merge1` (after one rollout's update: Carry's statistics).
Since commit 29dacc3 `merge` also zeroes the weights that read those inputs; before it, `merge1`
read them with their random initial weights.

    python results/laptop/diagnosis/unseen_probe.py CARRY_RUN_DIR FOLLOW_CHECKPOINT.pt
"""
import sys
from pathlib import Path

import torch

from detach import RunFolder, eval_config, load_policy, make_env, merge_normalizers, seed_everything


def rollout(actor, env, label: str) -> None:
    obs = env.get_observations()
    out = []
    with torch.no_grad():
        for t in range(150):
            a = actor(obs)
            obs, *_ = env.step(a)
            if t % 30 == 29:
                ctx = env.context()
                d = (ctx.obj_pos[:, :2] - ctx.state.root_pos[:, :2]).norm(dim=-1)
                out.append(f"t{t + 1} box {d.median():.2f} fwd {a[:, 32].mean():+.2f}")
    print(label, " | ".join(out), flush=True)


def main() -> None:
    cfg = eval_config(RunFolder(Path(sys.argv[1])).config(), None)
    checkpoint = Path(sys.argv[2])
    for mode in ("keep", "merge0", "merge1"):
        seed_everything(1)
        env = make_env(cfg, num_envs=16, device="cpu", eval_mode=True, verbose=False)
        actor, _ = load_policy(cfg, env, checkpoint)
        if mode != "keep":
            merge_normalizers(actor)
        if mode == "merge1":  # one rollout's statistics, then a fresh env for the measurement
            obs, seen = env.get_observations(), []
            with torch.no_grad():
                for _ in range(32):
                    seen.append(torch.cat([obs[g] for g in actor.obs_groups], -1))
                    obs, *_ = env.step(actor(obs))
            actor.obs_normalizer.train()
            actor.obs_normalizer.update(torch.cat(seen))
            actor.eval()
            env = make_env(cfg, num_envs=16, device="cpu", eval_mode=True, verbose=False)
        rollout(actor, env, mode)


if __name__ == "__main__":
    main()
