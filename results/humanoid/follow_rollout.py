"""How does a humanoid Follow policy fail? The run's development trials (evaluation envs, env
seed = run seed; never the test trials), mean actions, each env's first episode: how it ended
(a fall, the reference point too far ahead, the path's end reached), its length, the pelvis's
mean speed over the ground against the reference's, its mean distance behind the reference
point, and the share of its steps within the success distance of the path. With
`--assist TORQUE DAMPING` the same episodes are also played under the balance assist (the
training aid; never in an evaluation), which separates balance from gait: a policy that
walks to the path's end assisted and falls unassisted lacks balance, one that trails the
reference under the assist too lacks speed.

    python results/humanoid/follow_rollout.py RUN_DIR [--checkpoint FILE] [--envs 32] [--assist 500 15]
"""
from __future__ import annotations

import argparse
from pathlib import Path

import torch

from detach import RunFolder, load_policy, make_env, seed_everything


def rollout(cfg, checkpoint: Path, envs: int, assist: tuple[float, float]) -> str:
    """One line: outcomes and medians over the first episode of each of `envs` envs."""
    seed_everything(cfg.seed)
    env = make_env(cfg, num_envs=envs, device="cpu", eval_mode=True, verbose=False, seed=cfg.seed)
    actor, _ = load_policy(cfg, env, checkpoint)
    env.world.assist.set(*assist)
    obs = env.get_observations()
    live = torch.ones(envs, dtype=torch.bool)
    steps = torch.zeros(envs)
    travelled = torch.zeros(envs)
    ref_travelled = torch.zeros(envs)
    behind = torch.zeros(envs)
    outcome = ["running"] * envs
    ctx = env.context()
    pos, ref = ctx.state.root_pos[:, :2].clone(), ctx.ref_xy.clone()
    with torch.no_grad():
        for _ in range(cfg.env.episode_length):
            obs, _rew, dones, extras = env.step(actor(obs))
            ctx = env.context()
            done = dones.bool()
            step_live = live & ~done  # an env that ended this step has already been reset
            new_pos, new_ref = ctx.state.root_pos[:, :2], ctx.ref_xy
            travelled += torch.where(step_live, (new_pos - pos).norm(dim=-1), 0.0)
            ref_travelled += torch.where(step_live, (new_ref - ref).norm(dim=-1), 0.0)
            behind += torch.where(step_live, (new_pos - new_ref).norm(dim=-1), 0.0)
            steps += live.float()
            pos, ref = new_pos.clone(), new_ref.clone()
            for i in torch.nonzero(live & done).flatten().tolist():
                prog = extras["episode_progress"]
                ended = [k for k in ("fell", "traj_failed") if k in prog and bool(prog[k][i])]
                on_path = float(prog["on_path"][i, 0]) / max(float(prog["path_steps"][i, 0]), 1.0)
                outcome[i] = (ended[0] if ended else ("end" if bool(prog["done"][i]) else "time-out"),
                              on_path, float(prog["score"][i, 0]))
            live &= ~done
            if not bool(live.any()):
                break
    dt = env.dt
    counted = [o for o in outcome if o != "running"]
    kinds = {k: sum(1 for o in counted if o[0] == k) for k in ("fell", "traj_failed", "end", "time-out")}
    lived = steps.clamp(min=1)
    med = lambda v: float(v.median())  # noqa: E731
    return (f"assist {assist[0]:g}/{assist[1]:g}: ended by a fall {kinds['fell']}, reference too far ahead "
            f"{kinds['traj_failed']}, path's end {kinds['end']}, time-out {kinds['time-out']}, "
            f"running {envs - len(counted)}; success {sum(o[2] >= 1.0 for o in counted)}; medians: "
            f"{med(steps):.0f} steps, speed {med(travelled / (lived * dt)):.2f} m/s (reference "
            f"{med(ref_travelled / (lived * dt)):.2f}), {med(behind / lived):.2f} m from the reference, "
            f"{med(torch.tensor([o[1] for o in counted] or [0.0])):.2f} of steps on the path")


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path)
    parser.add_argument("--checkpoint", type=Path, help="default: the newest in the run's checkpoints/")
    parser.add_argument("--envs", type=int, default=32)
    parser.add_argument("--assist", type=float, nargs=2, metavar=("TORQUE", "DAMPING"))
    args = parser.parse_args()
    run = RunFolder(args.run)
    checkpoint = args.checkpoint or run.latest_checkpoint()
    if checkpoint is None:
        raise SystemExit(f"{args.run}: no checkpoint in checkpoints/")
    cfg = run.config()
    print(f"{args.run.name}, {checkpoint.name}, {args.envs} development trials, mean actions")
    for assist in [(0.0, 0.0)] + ([tuple(args.assist)] if args.assist else []):
        print(rollout(cfg, checkpoint, args.envs, assist), flush=True)


if __name__ == "__main__":
    main()
