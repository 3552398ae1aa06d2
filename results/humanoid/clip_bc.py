"""Behaviour-clone a humanoid actor on the motion clips' own hinge targets: a start for PPO.

    python results/humanoid/clip_bc.py RUN_OR_CONFIG OUT.pt [--rounds 60] [--steps 45]
        [--epochs 30] [--assist TORQUE DAMPING] [KEY=VALUE ...]

Each round resets every env of the run's training env at a reference state drawn from the
clips (`env.init=random`, Follow's own clips), then plays each clip open-loop for `--steps`
control steps: the action is the clip's next frame's hinge angles as PD targets
(`pd_actions`), and the pair (observation, that action) is kept while the episode lasts and
the clip has frames. The actor (its observation normaliser included) is then fitted to the
pairs by mean squared error, and the runner's checkpoint is written to OUT.pt, a start for
`train.init_from` (with `train.critic_warmup_iterations`, since its critic is untrained).
`--assist` collects under the balance assist (`train.balance_assist`).

It ends with a closed-loop check: the cloned actor (mean actions) from reference starts for
150 steps, without and with the assist: steps before the first episode end, distance walked.
Memory: the observations are kept in RAM (~8 kB each for the humanoid's Follow; 60 x 64 x 45
pairs ~ 1 GB).
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from detach.character.actions import pd_actions
from detach.config.loader import load_run_config
from detach.motion.builtin import default_motion_lib
from detach.torch_math import heading_matrix, yaw_of
from detach.train.motion_bridge import motion_label_weights, start_clip_labels, start_clip_probs
from detach.train.setup import build_runner


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("config", help="a run folder or its config.yaml (the humanoid_laptop run to start)")
    ap.add_argument("out", type=Path)
    ap.add_argument("--rounds", type=int, default=60)
    ap.add_argument("--steps", type=int, default=45)
    ap.add_argument("--epochs", type=int, default=30)
    ap.add_argument("--assist", type=float, nargs=2, default=(0.0, 0.0), metavar=("TORQUE", "DAMPING"))
    ap.add_argument("overrides", nargs="*")
    args = ap.parse_args()
    path = Path(args.config)
    cfg = load_run_config(path / "config.yaml" if path.is_dir() else path,
                          ["env.init=random", "train.max_iterations=1", *args.overrides])
    env, runner = build_runner(cfg, None, "cpu", log=None, progress=False)
    lib = default_motion_lib(device="cpu", skill_weights=motion_label_weights(cfg))
    probs = start_clip_probs(lib, start_clip_labels(cfg))
    drawn: dict[str, torch.Tensor] = {}

    def sample(n: int, gen: torch.Generator) -> dict[str, torch.Tensor]:
        """The env's reference-state sampler, remembering which clip and time each env got."""
        ids = torch.multinomial(probs, n, replacement=True, generator=gen)
        times = lib.sample_times(ids, generator=gen)
        s = lib.state(ids, times)
        R = heading_matrix(yaw_of(s.root_quat))
        drawn["ids"], drawn["times"] = ids, times
        return {"root_height": s.root_pos[:, 2], "root_quat": s.root_quat, "dof_pos": s.dof_pos,
                "dof_vel": s.dof_vel, "root_lin_vel": (s.root_lin_vel[:, None] @ R)[:, 0],
                "root_ang_vel": (s.root_ang_vel[:, None] @ R)[:, 0]}

    env.set_reference_sampler(sample)
    env.world.assist.set(*args.assist)
    lo, hi = env.character.dof_lo, env.character.dof_hi
    actor = runner.alg.actor
    obs_rows, act_rows, t0 = [], [], time.time()
    with torch.no_grad():
        for r in range(args.rounds):
            obs = env.reset()
            ids, times = drawn["ids"], drawn["times"]
            alive = torch.ones(env.num_envs, dtype=torch.bool)
            for k in range(args.steps):
                tk = times + (k + 1) * env.dt
                a = pd_actions(lib.state(ids, tk).dof_pos.float(), lo, hi)
                keep = alive & (tk <= lib.clip_length[ids])
                obs_rows.append(obs[keep].clone())
                act_rows.append(a[keep])
                obs, _, dones, _ = env.step(a)
                alive &= ~dones.bool()
            if r % 10 == 0 or r == args.rounds - 1:
                print(f"round {r}: {sum(len(a) for a in act_rows)} pairs, {float(alive.float().mean()):.2f} of "
                      f"the envs still up after {args.steps} steps, {time.time() - t0:.0f} s", flush=True)
    obs_all, act_all = torch.cat(obs_rows), torch.cat(act_rows)
    actor.update_normalization(obs_all)
    params = [p for name, p in actor.named_parameters() if "std" not in name]
    opt = torch.optim.Adam(params, lr=1e-3)
    n = act_all.shape[0]
    for epoch in range(args.epochs):
        perm, total = torch.randperm(n), 0.0
        for i in range(0, n, 4096):
            b = perm[i:i + 4096]
            loss = ((actor(obs_all[b]) - act_all[b]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(b)
        if epoch % 10 == 0 or epoch == args.epochs - 1:
            var = float(act_all.var(0).mean())
            print(f"epoch {epoch}: mse {total / n:.5f} (action variance {var:.5f})", flush=True)
    runner.save(str(args.out))
    print(f"wrote {args.out}")
    for gains in ((0.0, 0.0), tuple(args.assist)):
        env.world.assist.set(*gains)
        with torch.no_grad():
            obs, end = env.reset(), torch.full((env.num_envs,), 150)
            walked = torch.zeros(env.num_envs)
            for k in range(150):
                prev = env.state.root_pos[:, :2].clone()
                obs, _, dones, _ = env.step(actor(obs))
                live = end == 150
                walked[live] += (env.state.root_pos[live, :2] - prev[live]).norm(dim=-1)
                end[live & dones.bool()] = k + 1
        print(f"closed loop, assist {gains[0]:g}/{gains[1]:g}: {float(end.float().mean()):.1f} steps before the "
              f"first episode end, {float(walked.mean()):.2f} m walked")


if __name__ == "__main__":
    main()
