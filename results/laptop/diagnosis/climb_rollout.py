"""Where does a policy go in LH1's Climb subtask (or the single-skill climb task's)? 32 envs,
mean actions. In LH1 every episode starts at Climb from the scripted oracle's recorded states
(`env.subtask_start_prob=1`; the envs that started at Carry are left out). Every 30 control
steps, medians over the envs still in Climb: the pelvis's XY distance to the climb target and
its height against the target's, the soles' height against the top surface's, and how far the
climbed object has moved since the start; then the share of envs that reached Climb's success
distance.

    python results/laptop/diagnosis/climb_rollout.py RUN_DIR CHECKPOINT.pt
"""
import sys
from dataclasses import replace
from pathlib import Path

import torch

from detach import BODY_NAMES, FEET, FOOT_TO_SOLE, RunFolder, load_policy, make_training_env, seed_everything

NUM_ENVS = 32
FEET_IDS = [BODY_NAMES.index(b) for b in FEET]


def main() -> None:
    cfg = RunFolder(Path(sys.argv[1])).config()
    climb = list(cfg.task.plan).index("climb")
    if climb > 0:
        cfg = replace(cfg, env=replace(cfg.env, subtask_start_prob=1.0))
    seed_everything(1)
    env = make_training_env(cfg, num_envs=NUM_ENVS, device="cpu", verbose=False)  # with the recorded starts
    actor, _ = load_policy(cfg, env, Path(sys.argv[2]))
    obs = env.get_observations()
    ctx = env.context()
    climbing = ctx.subtask == climb
    print(f"{int(climbing.sum())} of {NUM_ENVS} envs start at Climb")
    box0 = ctx.obj_pos.clone()
    pelvis_height = cfg.env.climb_pelvis_height
    reached = torch.zeros(NUM_ENVS, dtype=torch.bool)
    with torch.no_grad():
        for t in range(300):
            obs, _rew, dones, _extras = env.step(actor(obs))
            climbing &= ~dones.bool()
            ctx = env.context()
            live = climbing & (ctx.subtask == climb)
            dxy = (ctx.state.root_pos[:, :2] - ctx.target[:, :2]).norm(dim=-1)
            dz = ctx.state.root_pos[:, 2] - ctx.target[:, 2]
            soles = ctx.state.body_pos[:, FEET_IDS, 2].mean(dim=-1) - FOOT_TO_SOLE
            top = ctx.target[:, 2] - pelvis_height
            moved = (ctx.obj_pos[:, :2] - box0[:, :2]).norm(dim=-1)
            reached |= live & (torch.sqrt(dxy ** 2 + dz.clamp(max=0) ** 2) <= cfg.env.success_threshold)
            if t % 30 == 29 and bool(live.any()):
                med = lambda v: float(v[live].median())  # noqa: E731
                print(f"t{t + 1}: in climb {int(live.sum())}, pelvis xy to target {med(dxy):.2f} m, "
                      f"pelvis z - target z {med(dz):+.2f} m, soles - top {med(soles - top):+.2f} m, "
                      f"object moved {med(moved):.2f} m, top at {med(top):.2f} m", flush=True)
    print(f"envs within the success distance at least once: {int(reached.sum())}")


if __name__ == "__main__":
    main()
