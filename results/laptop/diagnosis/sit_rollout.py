"""Where does a policy go in LH1's Sit subtask? 32 envs, mean actions, every episode from the
scripted oracle's recorded Sit starts (on the box beside the platform; `env.subtask_start_prob=1`)
of a run whose plan has Sit after another subtask (e.g. S2's `[climb, sit]`). Every 20 control
steps, medians over the envs still in the episode: the pelvis position, its XY distance to the
sit point and its height against it; then how many envs held the sit point (3-D distance <=
0.3 m) for 20 consecutive steps, the evaluation's transition rule.

    python results/laptop/diagnosis/sit_rollout.py ENV_RUN_DIR CHECKPOINT.pt [POLICY_RUN_DIR]

POLICY_RUN_DIR (default ENV_RUN_DIR) is the run whose config builds the checkpoint's network.
"""
import sys
from dataclasses import replace
from pathlib import Path

import torch

from detach import RunFolder, load_policy, make_training_env, seed_everything

NUM_ENVS, STEPS, HOLD = 32, 450, 20


def main() -> None:
    cfg = RunFolder(Path(sys.argv[1])).config()
    sit = list(cfg.task.plan).index("sit")
    if sit == 0:
        raise SystemExit("the plan must have Sit after another subtask (its starts are the oracle's)")
    cfg = replace(cfg, env=replace(cfg.env, subtask_start_prob=1.0))
    policy_cfg = RunFolder(Path(sys.argv[3])).config() if len(sys.argv) > 3 else cfg
    seed_everything(1)
    env = make_training_env(cfg, num_envs=NUM_ENVS, device="cpu", verbose=False)  # with the recorded starts
    actor, _ = load_policy(policy_cfg, env, Path(sys.argv[2]))
    obs = env.get_observations()
    live = env.context().subtask == sit
    print(f"{int(live.sum())} of {NUM_ENVS} envs start at Sit")
    hold = torch.zeros(NUM_ENVS)
    held = torch.zeros(NUM_ENVS, dtype=torch.bool)
    with torch.no_grad():
        for t in range(STEPS):
            obs, _rew, dones, _extras = env.step(actor(obs))
            live &= ~dones.bool()
            ctx = env.context()
            hold = torch.where(live & (ctx.dist <= 0.3), hold + 1, torch.zeros_like(hold))
            held |= hold >= HOLD
            if t % 20 == 19 and bool(live.any()):
                p, target = ctx.state.root_pos[live], ctx.target[live]
                dxy = float((p[:, :2] - target[:, :2]).norm(dim=-1).median())
                dz = float((p[:, 2] - target[:, 2]).median())
                print(f"t{t + 1}: live {int(live.sum())}, pelvis {[round(float(x), 2) for x in p.median(0).values]}, "
                      f"xy to the sit point {dxy:.2f} m, height against it {dz:+.2f} m", flush=True)
    print(f"envs that held the sit point for {HOLD} steps: {int(held.sum())}")


if __name__ == "__main__":
    main()
