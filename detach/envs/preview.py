"""Run one episode of a task headless and print its subtask timeline.

    python -m detach.envs.preview configs/tasks/lh1.yaml --oracle
    python -m detach.envs.preview configs/tasks/lh3.yaml --random --character humanoid

`--oracle` drives a scriptable character (the puppet) with `detach.envs.oracle.Oracle` and
picks that character unless `--character` names another scriptable one; `--random` samples
uniform actions; without either, zero actions (the default pose). Evaluation settings apply
(`eval.max_transition_steps`). `--save` writes the character's and objects' world poses per
control step to an .npz file.
"""

from __future__ import annotations

import argparse
import sys
import time
from typing import Sequence

import numpy as np
import torch


def _fmt_time(steps: int, dt: float) -> str:
    return "-" if steps < 0 else f"{steps * dt:6.2f}"


def timeline(env, prog: dict, i: int = 0) -> str:
    """A table of env i's subtasks: skill, target source, start/end/duration (s), score."""
    src = env.cfg.task.sample_target_from
    rows = ["  #  skill  target      start s   end s   took s  score"]
    for k, s in enumerate(env.plan):
        st, en = int(prog["start"][i, k]), int(prog["end"][i, k])
        took = f"{(en - st) * env.dt:6.2f}" if en >= 0 else "     -"
        rows.append(f"  {k}  {s.skill:<6} {src[k]:<10} {_fmt_time(st, env.dt):>8} {_fmt_time(en, env.dt):>7} "
                    f"{took:>8}  {float(prog['score'][i, k]):.1f}")
    return "\n".join(rows)


def main(argv: Sequence[str] | None = None) -> int:
    from detach.character import character_names, scriptable_characters

    ap = argparse.ArgumentParser(prog="python -m detach.envs.preview", description=__doc__.splitlines()[0])
    ap.add_argument("task", help="task YAML, e.g. configs/tasks/lh1.yaml")
    mode = ap.add_mutually_exclusive_group()
    mode.add_argument("--oracle", action="store_true", help="scripted privileged controller (needs a "
                      f"scriptable character: {', '.join(scriptable_characters())})")
    mode.add_argument("--random", action="store_true", help="uniform random actions")
    ap.add_argument("--character", choices=character_names(), default=None)
    ap.add_argument("--seed", type=int, default=0)
    ap.add_argument("--save", default=None, help="write per-step body poses to this .npz")
    ap.add_argument("overrides", nargs="*", help="config overrides key=value")
    args = ap.parse_args(argv)

    from detach.character.body import BODY_NAMES
    from detach.config import ConfigError, resolve
    from detach.envs.lh_env import make_env
    from detach.envs.oracle import Oracle, random_policy

    torch.set_num_threads(1)
    overrides = list(args.overrides)
    character = args.character
    if args.oracle and character not in scriptable_characters():
        if character is not None:
            ap.error(f"--oracle drives a scriptable character ({', '.join(scriptable_characters())}); "
                     f"drop --character {character}")
        character = scriptable_characters()[0]
    if character:
        overrides.append(f"env.character={character}")
    try:
        cfg = resolve(args.task, "mlp", overrides, seed=args.seed)
    except ConfigError as e:
        print(f"error: {e}", file=sys.stderr)
        return 2
    env = make_env(cfg, num_envs=1, eval_mode=True, verbose=True)
    if args.oracle:
        policy = Oracle(env)
    elif args.random:
        policy = random_policy(env, torch.Generator().manual_seed(args.seed))
    else:
        policy = lambda _e=None: torch.zeros(1, env.num_actions)  # noqa: E731
    frames: list[np.ndarray] = []
    names = [*BODY_NAMES, *(o.body_name for o in env.scene.objects)]
    t0, sub = time.time(), 0
    print(f"\nepisode (dt {env.dt:.4f} s, limit {env.max_episode_length} steps):")
    while True:
        _, _, dones, extras = env.step(policy(env.get_observations()))
        if args.save:
            st = env.state
            pos, quat = torch.cat((st.body_pos[0], st.obj_pos[0])), torch.cat((st.body_quat[0], st.obj_quat[0]))
            frames.append(torch.cat((pos, quat), -1).numpy())
        step = int(extras["episode_progress"]["length"][0]) if dones[0] else int(env.steps[0])
        new_sub = int(extras["episode_progress"]["subtask"][0]) if dones[0] else int(env.tracker.subtask[0])
        if new_sub != sub:
            print(f"  t = {step * env.dt:6.2f} s  subtask {sub} ({env.plan[sub].skill}) complete -> "
                  f"{new_sub} ({env.plan[new_sub].skill})")
            sub = new_sub
        if dones[0]:
            prog = extras["episode_progress"]
            why = ("fell" if prog["fell"][0] else "left the trajectory" if prog["traj_failed"][0]
                   else "plan complete" if prog["done"][0, -1] else "time limit")
            print(f"  t = {step * env.dt:6.2f} s  episode ends: {why}\n")
            print(timeline(env, prog))
            print(f"\nLH success: {bool(prog['lh_success'][0])}   episode {step} steps = {step * env.dt:.2f} s "
                  f"(simulated in {time.time() - t0:.1f} s wall)")
            break
    if args.save:
        np.savez_compressed(args.save, poses=np.stack(frames), bodies=np.array(names), dt=env.dt)
        print(f"wrote {args.save}: {len(frames)} frames x {len(names)} bodies (xyz + wxyz)")
    return 0


if __name__ == "__main__":
    sys.exit(main())
