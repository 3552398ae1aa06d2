"""Adam variants on the parameters of our actor + critic, side by side in one run.

Why: PPO's optimiser step was the largest cost of a CPU training iteration (rsl-rl builds a
plain `torch.optim.Adam`, whose CPU path loops over tensors); `AmpPPO` rebuilds it fused.

    python benchmarks/bench_optimizer.py [--model mlp] [--reps 10]
"""

from __future__ import annotations

import argparse
import time
from pathlib import Path

import torch

from detach import build_actor_critic, make_env, resolve
from scene_builder.assets import ensure_assets


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    parser.add_argument("--model", default="mlp")
    parser.add_argument("--reps", type=int, default=10)
    args = parser.parse_args()
    torch.set_num_threads(1)
    root = Path(__file__).resolve().parents[1]
    cfg = resolve(root / "configs/tasks/follow.yaml", args.model, ["env.character=puppet"])
    ensure_assets(cfg.task)
    env = make_env(cfg, num_envs=2, verbose=False)
    actor, critic = build_actor_critic(cfg.model, env.obs_spec, env.get_observations(),
                                       num_actions=env.num_actions)
    params = [p for m in (actor, critic) for p in m.parameters()]
    for p in params:
        p.grad = torch.randn_like(p)
    count = sum(p.numel() for p in params)
    print(f"{args.model}: {count / 1e6:.2f} M parameters in {len(params)} tensors, 1 thread")
    times = {}
    for name, kw in (("plain (rsl-rl default)", {}), ("foreach", {"foreach": True}),
                     ("fused (AmpPPO)", {"fused": True})):
        opt = torch.optim.Adam(params, lr=1e-4, **kw)
        opt.step()
        start = time.perf_counter()
        for _ in range(args.reps):
            opt.step()
        times[name] = (time.perf_counter() - start) / args.reps
    base = times["plain (rsl-rl default)"]
    for name, t in times.items():
        print(f"  {name:24s} {t * 1000:8.1f} ms/step   {base / t:5.2f}x plain")


if __name__ == "__main__":
    main()
