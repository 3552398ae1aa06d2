"""Where the env step's small torch ops are: aten ops per `LHEnv.step` by part, and each part's
wall time, at N = 64 (humanoid, LH3 by default, zero actions).

The env's own work on the CPU is bounded by the number of small eager ops (each a few
microseconds at these sizes), not by arithmetic, so the op count per part says where a
rewrite would pay (issue 18 item 6 asks for env/raw >= 0.8, which `bench_env.py` measures).
Op counts are exact (a `TorchDispatchMode`); times are as good as the machine is idle.

With --compile the env runs with `sim.compile=true` and the parts are its compiled groups
(`_judge`, `_context`, `_observe`, each one `torch.compile` graph), timed only: under the
counting mode a compiled graph would run its ops one by one again.

    python benchmarks/env_step_ops.py [--task configs/tasks/lh3.yaml] [--n 64] [--steps 300] [--compile]
"""

from __future__ import annotations

import argparse
import collections
import time

import torch
from torch.utils._python_dispatch import TorchDispatchMode

COMPILED_PARTS = (("character", "pre_step"), ("character", "controls"), ("backend", "step"), ("env", "_read"),
                  ("env", "_judge"), ("env", "_context"), ("env", "_reset_envs"), ("env", "_observe"),
                  ("tracker", "progress"), ("tracker", "episode_log"))
PARTS = (("character", "pre_step"), ("character", "controls"), ("backend", "step"), ("env", "_read"),
         ("env", "context"), ("rewards", "compute"), ("terminations", "compute"), ("tracker", "advance"),
         ("tracker", "progress"), ("tracker", "episode_log"), ("env", "_reset_envs"), ("env", "_observe"))


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    ap.add_argument("--task", default="configs/tasks/lh3.yaml")
    ap.add_argument("--n", type=int, default=64)
    ap.add_argument("--steps", type=int, default=300)
    ap.add_argument("--compile", action="store_true", help="the env with sim.compile=true")
    args = ap.parse_args()
    torch.set_num_threads(1)
    from detach import make_env, resolve
    from scene_builder.assets import ensure_assets

    cfg = resolve(args.task, "mlp", ["env.character=humanoid", "sim.nthread=2", f"sim.compile={args.compile}"])
    ensure_assets(cfg.task)
    env = make_env(cfg, num_envs=args.n, verbose=False)
    seconds: dict[str, float] = collections.defaultdict(float)
    ops: dict[str, int] = collections.defaultdict(int)
    stack: list[str] = []

    class CountOps(TorchDispatchMode):
        def __torch_dispatch__(self, func, types, a=(), kw=None):
            ops[stack[-1] if stack else "step (rest)"] += 1
            return func(*a, **(kw or {}))

    def timed(owner, name: str, key: str) -> None:
        fn = getattr(owner, name)

        def wrapper(*a, **kw):
            stack.append(key)
            t0 = time.perf_counter()
            try:
                return fn(*a, **kw)
            finally:
                seconds[key] += time.perf_counter() - t0
                stack.pop()
        setattr(owner, name, wrapper)

    owners = {"character": env.character, "backend": env.backend, "env": env, "rewards": env.rewards,
              "terminations": env.terminations, "tracker": env.tracker}
    for owner, name in COMPILED_PARTS if args.compile else PARTS:
        timed(owners[owner], name, f"{owner}.{name}")
    act = torch.zeros(args.n, env.num_actions)
    for _ in range(100):  # warm-up; with --compile also the recompiles of lazily set state
        env.step(act)
    seconds.clear()
    t0 = time.perf_counter()
    for _ in range(args.steps):
        env.step(act)
    total = time.perf_counter() - t0
    counted = 0 if args.compile else 50
    with CountOps():
        for _ in range(counted):
            env.step(act)
    count = (lambda n: f"{n / counted:.1f}") if counted else (lambda n: "-")
    print(f"{args.task}{' (sim.compile)' if args.compile else ''}, N = {args.n}: "
          f"{total / args.steps * 1e3:.2f} ms per step, {count(sum(ops.values()))} aten ops per step")
    print("| part | ms per step | aten ops per step |\n| --- | --- | --- |")
    for key in sorted(set(seconds) | set(ops), key=lambda k: (-ops.get(k, 0), -seconds.get(k, 0.0))):
        print(f"| {key} | {seconds.get(key, 0.0) / args.steps * 1e3:.3f} | {count(ops.get(key, 0))} |")


if __name__ == "__main__":
    main()
