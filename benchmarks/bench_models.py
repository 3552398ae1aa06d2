"""Forward+backward time of every network of the study vs the MLP baseline (CPU).

One PPO-like step per repetition on a batch of 4096 random observations shaped like
`EXAMPLE_SPEC`: actor forward (stochastic, log-prob) + critic forward + backward of
a surrogate-like scalar. DETACH also gets a line with its auxiliary losses added
(`aux_losses` on the same obs, reusing the forward's encoder outputs: the joint-stage cost).
Models are timed round-robin (min and median of `--reps`), so load from other processes on a
shared machine hits all of them alike. Threads: `torch.set_num_threads(1)` by default (what
training uses, see LIBRARY_NOTES.md); `--threads 2` to compare.

Run: /work/venv/bin/python benchmarks/bench_models.py [--batch 4096] [--reps 5] [--threads 1]
"""

from __future__ import annotations

import argparse
import os
import platform
import statistics
import time

import torch
from tensordict import TensorDict

from detach.config.schema import ModelCfg
from detach.models.cml import CMLCfg
from detach.models.detach_net import DetachCfg
from detach.models.mlp import MLPCfg
from detach.models.tokenhsi import TokenHSICfg
from detach.envs.obs_spec import EXAMPLE_SPEC
from detach.models import build_actor_critic

CONFIGS: dict[str, ModelCfg] = {
    "mlp": MLPCfg(),
    "detach": DetachCfg(),
    "ablation_a1": DetachCfg(use_env_encoder=False),
    "ablation_a2": DetachCfg(use_self_encoder=False),
    "tokenhsi": TokenHSICfg(num_heads=2, ff_dim=512),
    "cml": CMLCfg(critic_objectives=("task", "disc_upper", "disc_lower")),
}


def random_obs(n: int) -> TensorDict:
    return TensorDict({g: torch.randn(n, d) for g, d in EXAMPLE_SPEC.group_dims().items()}, batch_size=[n])


def step(actor, critic, obs: TensorDict, with_aux: bool) -> None:
    actions = actor(obs, stochastic_output=True).detach()
    loss = -actor.get_output_log_prob(actions).mean() + critic(obs).pow(2).mean()
    if with_aux:
        loss = loss + sum(actor.aux_losses(obs, reuse_forward=True).values())
    loss.backward()


def count(m: torch.nn.Module) -> int:
    return sum(p.numel() for p in m.parameters())


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--batch", type=int, default=4096)
    ap.add_argument("--reps", type=int, default=5)
    ap.add_argument("--threads", type=int, default=1)
    args = ap.parse_args()
    torch.set_num_threads(args.threads)
    obs = random_obs(args.batch)
    torch.manual_seed(0)
    cases = {name: (*build_actor_critic(cfg, EXAMPLE_SPEC, obs), False) for name, cfg in CONFIGS.items()}
    cases["detach+aux"] = (*cases["detach"][:2], True)
    times: dict[str, list[float]] = {name: [] for name in cases}
    for name, (actor, critic, aux) in cases.items():  # warm-up
        step(actor, critic, obs, aux)
    # Round-robin over the models so that load from other processes hits all of them alike.
    for _ in range(args.reps):
        for name, (actor, critic, aux) in cases.items():
            actor.zero_grad(set_to_none=True)
            critic.zero_grad(set_to_none=True)
            t0 = time.perf_counter()
            step(actor, critic, obs, aux)
            times[name].append(time.perf_counter() - t0)
    print(f"torch {torch.__version__}, {platform.machine()}, {os.cpu_count()} cores, threads={args.threads}, "
          f"batch={args.batch}, T_self={EXAMPLE_SPEC.self_steps}, T_env={EXAMPLE_SPEC.env_steps}, "
          f"{args.reps} round-robin reps, load average {os.getloadavg()[0]:.2f}")
    base_min, base_med = min(times["mlp"]), statistics.median(times["mlp"])
    print("| model | fwd+bwd min (s) | x MLP (min) | median (s) | x MLP (median) | actor params | critic params |")
    print("|---|---|---|---|---|---|---|")
    for name, (actor, critic, _) in cases.items():
        t_min, t_med = min(times[name]), statistics.median(times[name])
        print(f"| {name} | {t_min:.3f} | {t_min / base_min:.2f} | {t_med:.3f} | {t_med / base_med:.2f} "
              f"| {count(actor) / 1e6:.2f} M | {count(critic) / 1e6:.2f} M |")


if __name__ == "__main__":
    main()
