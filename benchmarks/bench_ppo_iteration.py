"""Cost of one PPO iteration on the puppet follow task, split by part, side by side in one run.

    python benchmarks/bench_ppo_iteration.py [--models detach detach-separate mlp] [--reps 2]

For each variant: a rollout (64 envs x 32 steps, the training defaults), one forward+backward
of actor and critic together on a 512-sample mini-batch (as PPO's loss does), the auxiliary
losses (DETACH), and the whole `update()` (20 mini-batches + AMP + aux), DETACH in its stage 2
(fusion). `detach` is configs/models/detach.yaml (critic on the actor's trunk,
`model.shared_trunk: true`); `detach-separate` gives the critic its own DETACH trunk (as before
the shared trunk); `detach-transposed` is `detach-separate` with Φ_env's conv features left as a
transposed view (before the `.contiguous()` in `EnvEncoder.conv_features`), to keep that fix
measured. Variants are timed round-robin (median of `--reps`), threads as in training.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path

import torch

from detach import EnvEncoder, build_runner, resolve

ROOT = Path(__file__).resolve().parents[1]


VARIANTS: dict[str, tuple[str, list[str]]] = {
    "detach": ("detach", []),
    "detach-separate": ("detach", ["model.shared_trunk=false"]),
    "detach-transposed": ("detach", ["model.shared_trunk=false"]),
    "mlp": ("mlp", []),
}
"""variant -> (model config, overrides)."""


def variant_context(name: str):
    """The code state a variant is built and timed in."""
    return transposed_env_features() if name == "detach-transposed" else nullcontext()


@contextmanager
def transposed_env_features():
    """Φ_env's conv features as the transposed view they were before the fix."""
    original = EnvEncoder.conv_features

    def conv_features(self, x: torch.Tensor) -> torch.Tensor:
        e = self.embed(x).transpose(1, 2)
        return torch.cat([self.act(conv(e)) for conv in self.convs], dim=1).transpose(1, 2)

    EnvEncoder.conv_features = conv_features
    try:
        yield
    finally:
        EnvEncoder.conv_features = original


def build(variant: str):
    model, overrides = VARIANTS[variant]
    cfg = resolve(ROOT / "configs/tasks/follow.yaml", model,
                  ["env.character=puppet", "train.stages.pretrain=1", "train.stages.fusion=1000",
                   *overrides])
    env, runner = build_runner(cfg, None, "cpu", progress=False)
    runner.learn(2)  # DETACH: stage 1, then the first stage-2 iteration (warm-up for all)
    return env, runner


def measure(env, runner) -> dict[str, float]:
    alg = runner.alg
    obs = env.get_observations()
    start = time.perf_counter()
    with torch.inference_mode():
        for _ in range(runner.cfg["num_steps_per_env"]):
            obs, rew, dones, extras = env.step(alg.act(obs))
            alg.process_env_step(obs, rew, dones, extras)
        alg.compute_returns(obs)
    out = {"rollout": time.perf_counter() - start}
    batch = alg.storage.observations.flatten(0, 1)[:512]
    start = time.perf_counter()
    (alg.actor(batch).sum() + alg.critic(batch).sum()).backward()
    out["actor+critic fwd+bwd"] = time.perf_counter() - start
    if alg.aux_loss_fn is not None:
        start = time.perf_counter()
        alg.aux_loss_fn(batch, alg.stage)[0].backward()
        out["aux fwd+bwd"] = time.perf_counter() - start
    alg.optimizer.zero_grad()
    start = time.perf_counter()
    alg.update()
    out["update"] = time.perf_counter() - start
    return out


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", choices=list(VARIANTS),
                    default=["detach", "detach-separate", "mlp"])
    ap.add_argument("--reps", type=int, default=2)
    args = ap.parse_args()
    variants = {}
    for name in args.models:
        with variant_context(name):
            variants[name] = build(name)
    times: dict[str, list[dict[str, float]]] = {name: [] for name in variants}
    for _ in range(args.reps):
        for name, (env, runner) in variants.items():
            with variant_context(name):
                times[name].append(measure(env, runner))
    parts = sorted({k for reps in times.values() for r in reps for k in r},
                   key=["rollout", "actor+critic fwd+bwd", "aux fwd+bwd", "update"].index)
    print(f"torch {torch.__version__}, {os.cpu_count()} cores, threads={torch.get_num_threads()}, "
          f"puppet follow, 64 envs x 32 steps, mini-batch 512, median of {args.reps}")
    print("| variant | " + " | ".join(f"{p} (s)" for p in parts) + " | rollout + update (s) |")
    print("|---" * (len(parts) + 2) + "|")
    for name, reps in times.items():
        med = {p: statistics.median(r[p] for r in reps) for p in parts if p in reps[0]}
        cells = [f"{med[p]:.3f}" if p in med else "-" for p in parts]
        print(f"| {name} | " + " | ".join(cells) + f" | {med['rollout'] + med['update']:.2f} |")


if __name__ == "__main__":
    main()
