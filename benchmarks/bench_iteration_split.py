"""One PPO iteration split into its parts, for every model kind and character, side by side.

    python benchmarks/bench_iteration_split.py [--models mlp detach tokenhsi cml]
        [--characters puppet humanoid] [--reps 3] [overrides ...]

A model may carry its own overrides, each after an `@`, to time a change against the code
without it in one run, e.g. `--models mlp detach detach@train.reuse_frozen_features=false`.

Follow task, `sim.num_envs` x `train.num_steps_per_env` (64 x 32, the training defaults), one
torch thread. Rollout: the env's step, the policy's inference (`alg.act`: actor and critic),
the AMP discriminator's style reward, the rest (storage, GAE). Update: PPO's epochs
(`num_learning_epochs` x `num_mini_batches`), the discriminator's updates, DETACH's auxiliary
losses (their own pass over the rollout). DETACH is in its stage 2 (fusion), as most of a run.

Variants are timed round-robin, one iteration each per round; the
figures are medians over `--reps` rounds. Both wall seconds and the process's CPU seconds are
printed: on a shared machine the CPU seconds are the steadier measure of the work done.
"""

from __future__ import annotations

import argparse
import os
import statistics
import time
from contextlib import contextmanager, nullcontext
from pathlib import Path
from typing import Callable, Iterator

import torch

from detach import build_runner, resolve

ROOT = Path(__file__).resolve().parents[1]
PARTS = ("env", "policy", "amp reward", "rollout other", "rollout",
         "ppo", "discriminator", "aux", "update", "iteration")


class Clock:
    """Wall and process-CPU seconds accumulated per part."""

    def __init__(self) -> None:
        self.wall: dict[str, float] = {}
        self.cpu: dict[str, float] = {}

    @contextmanager
    def part(self, name: str) -> Iterator[None]:
        w, c = time.perf_counter(), time.process_time()
        try:
            yield
        finally:
            self.wall[name] = self.wall.get(name, 0.0) + time.perf_counter() - w
            self.cpu[name] = self.cpu.get(name, 0.0) + time.process_time() - c

    def timed(self, name: str, fn: Callable) -> Callable:
        def wrapper(*args, **kwargs):
            with self.part(name):
                return fn(*args, **kwargs)
        return wrapper


class Variant:
    """One model on one character, its runner built and warmed up, its parts instrumented."""

    def __init__(self, spec: str, character: str, overrides: list[str]) -> None:
        self.name = spec
        model, *own = spec.split("@")
        overrides = [*overrides, *own]
        self.character = character
        self.context = nullcontext
        """A code state to build and time the variant in (e.g. one patching a change back out)."""
        cfg = resolve(ROOT / "configs/tasks/follow.yaml", model,
                      [f"env.character={character}", "train.stages.pretrain=1",
                       "train.stages.fusion=1000", "train.torch_threads=1", *overrides])
        with self.context():
            self.env, self.runner = build_runner(cfg, None, "cpu", progress=False)
            torch.set_num_threads(1)
            self.runner.learn(2)  # DETACH: stage 1, then the first stage-2 iteration (warm-up for all)
        self.clock = Clock()
        alg = self.runner.alg
        alg._style_rewards = self.clock.timed("amp reward", alg._style_rewards)
        alg._update_discriminators = self.clock.timed("discriminator", alg._update_discriminators)
        alg._update_aux = self.clock.timed("aux", alg._update_aux)
        self.env_step = self.clock.timed("env", self.env.step)
        self.act = self.clock.timed("policy", alg.act)

    def iteration(self) -> tuple[dict[str, float], dict[str, float]]:
        """One rollout and update, as the runner does them; (wall, cpu) seconds per part."""
        self.clock.wall.clear()
        self.clock.cpu.clear()
        alg, clock = self.runner.alg, self.clock
        alg.train_mode()
        with self.context(), clock.part("iteration"):
            obs = self.env.get_observations()
            with clock.part("rollout"), torch.inference_mode():
                for _ in range(self.runner.cfg["num_steps_per_env"]):
                    obs, rew, dones, extras = self.env_step(self.act(obs))
                    alg.process_env_step(obs, rew, dones, extras)
                alg.compute_returns(obs)
            with clock.part("update"):
                alg.update()
        for times in (clock.wall, clock.cpu):
            times.setdefault("discriminator", 0.0)
            times.setdefault("aux", 0.0)
            times.setdefault("amp reward", 0.0)
            times["rollout other"] = times["rollout"] - times["env"] - times["policy"] - times["amp reward"]
            times["ppo"] = times["update"] - times["discriminator"] - times["aux"]
        return dict(clock.wall), dict(clock.cpu)


def table(title: str, results: dict[tuple[str, str], list[dict[str, float]]]) -> None:
    """Median seconds per part, and the iteration's ratio to the MLP on the same character."""
    print(f"\n{title}")
    cols = list(PARTS)
    print("| character | variant | " + " | ".join(cols) + " | x MLP (rollout / update / iteration) |")
    print("|---" * (len(cols) + 3) + "|")
    med = {key: {p: statistics.median(r[p] for r in reps) for p in cols} for key, reps in results.items()}
    for (character, name), m in med.items():
        base = med.get((character, "mlp"))
        ratio = " / ".join(f"{m[p] / base[p]:.2f}" for p in ("rollout", "update", "iteration")) if base else "-"
        print(f"| {character} | {name} | " + " | ".join(f"{m[p]:.3f}" for p in cols) + f" | {ratio} |")


def main() -> None:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--models", nargs="+", default=["mlp", "detach", "tokenhsi", "cml"])
    ap.add_argument("--characters", nargs="+", default=["puppet", "humanoid"])
    ap.add_argument("--reps", type=int, default=3)
    ap.add_argument("overrides", nargs="*", help="config overrides for every variant, e.g. sim.num_envs=64")
    args = ap.parse_args()
    torch.set_num_threads(1)
    variants = []
    for character in args.characters:
        for model in args.models:
            variants.append(Variant(model, character, args.overrides))
    wall: dict[tuple[str, str], list[dict[str, float]]] = {(v.character, v.name): [] for v in variants}
    cpu: dict[tuple[str, str], list[dict[str, float]]] = {(v.character, v.name): [] for v in variants}
    for rep in range(args.reps):
        for v in variants:
            w, c = v.iteration()
            wall[(v.character, v.name)].append(w)
            cpu[(v.character, v.name)].append(c)
            print(f"round {rep + 1}: {v.character} {v.name} {w['iteration']:.2f} s wall, "
                  f"{c['iteration']:.2f} s cpu", flush=True)
    cfg = variants[0].runner.cfg
    print(f"\ntorch {torch.__version__}, {os.cpu_count()} cores, torch threads 1, follow task, "
          f"{variants[0].env.num_envs} envs x {cfg['num_steps_per_env']} steps, "
          f"load average {os.getloadavg()[0]:.1f}, median of {args.reps} rounds")
    table("Process CPU seconds per iteration", cpu)
    table("Wall seconds per iteration", wall)


if __name__ == "__main__":
    main()
