"""Where an evaluation's wall time goes: the rollout at several `eval.num_envs`, the
recording of every trial, and reopening the run's log.mcap to append to it.

A 100-trial evaluation runs its trials on `eval.num_envs` parallel envs, each env playing its
quota of episodes one after another. A step of N envs costs far less than N steps of one env
(the env's own work is mostly per-step overhead at small N), so fewer rounds of wider steps
finish sooner; this script measures by how much, side by side in one process, and prints
the success rates too (same policy, different envs per trial, so they differ only by
sampling). Then, at the first N, what `detach-run eval` adds on the run's own task: reopening
a copy of the run's log.mcap with append=True (MCAP files cannot be appended to, so every
earlier message is copied into a fresh file) and the same rollout recording each trial into it.

    python benchmarks/bench_eval.py RUN_DIR [--task TASK] [--trials 100] [--num-envs 16 50 100]

The first N is the one the recorded variants use (16 = `eval.num_envs` of the shipped tasks).
"""

from __future__ import annotations

import argparse
import dataclasses
import shutil
import tempfile
import time
from pathlib import Path


def main() -> None:
    parser = argparse.ArgumentParser(description=__doc__.split("\n\n")[0])
    parser.add_argument("run", type=Path, help="a run folder with a checkpoint")
    parser.add_argument("--task", type=Path, default=None, help="evaluate on another task (YAML)")
    parser.add_argument("--trials", type=int, default=100)
    parser.add_argument("--num-envs", type=int, nargs="+", default=[16, 50, 100])
    args = parser.parse_args()

    from detach import (
        RunFolder, apply_torch_threads, eval_config, load_policy, make_env, newest_readable_checkpoint, prepare_assets,
        run_evaluation, seed_everything,
    )

    run = RunFolder(args.run)
    base = eval_config(run.config(), args.task)
    checkpoint = newest_readable_checkpoint(run.path, "cpu")
    prepare_assets(base.task)
    apply_torch_threads(base)
    rows = []
    for n in args.num_envs:
        cfg = dataclasses.replace(base, eval=dataclasses.replace(base.eval, num_envs=n))
        seed_everything(cfg.seed + 1)
        env = make_env(cfg, num_envs=min(n, args.trials), device="cpu", eval_mode=True)
        actor, _ = load_policy(cfg, env, checkpoint, "cpu")
        t0 = time.perf_counter()
        result = run_evaluation(env, lambda obs: actor(obs), args.trials, cfg, progress=False)
        rows.append((n, time.perf_counter() - t0, result))
        print(f"num_envs {n}: {rows[-1][1]:.1f} s", flush=True)
    first = dataclasses.replace(base, eval=dataclasses.replace(base.eval, num_envs=args.num_envs[0]))
    copy_s, decoded_copy_s, recorded_s = record(run, first, checkpoint, args.trials)
    print(f"\n{run.path.name} ({checkpoint.name}) on {base.task_name}, {args.trials} trials")
    print("| num_envs | rollout s | speed-up vs first | LH mean | LH chain |")
    print("| --- | --- | --- | --- | --- |")
    for n, seconds, result in rows:
        print(f"| {n} | {seconds:.1f} | {rows[0][1] / seconds:.2f}x | {result.lh_mean.rate:.2f} "
              f"[{result.lh_mean.ci[0]:.2f}, {result.lh_mean.ci[1]:.2f}] | {result.lh_chain.rate:.2f} |")
    size = run.log_path.stat().st_size / 2 ** 20 if run.log_path.exists() else 0.0
    print(f"\nreopening the {size:.0f} MiB log.mcap to append: {copy_s:.1f} s (bytes passed through), "
          f"{decoded_copy_s:.1f} s if every message is decoded and re-encoded ({decoded_copy_s / copy_s:.1f}x)")
    print(f"at num_envs {rows[0][0]}, the rollout recording every trial: {recorded_s:.1f} s "
          f"(without recording {rows[0][1]:.1f} s)")


def record(run, cfg, checkpoint: Path, trials: int) -> tuple[float, float, float]:
    """(seconds to reopen a copy of the run's log for appending, the same copy made by decoding
    and re-encoding every message, seconds of the rollout that records every trial into the
    log), as `detach-run eval` does on the run's own task."""
    from detach import RunLogWriter, iter_messages, load_policy, make_env, run_evaluation, seed_everything

    with tempfile.TemporaryDirectory() as tmp:
        log_path = Path(tmp) / "log.mcap"
        if run.log_path.exists():
            shutil.copyfile(run.log_path, log_path)
        t0 = time.perf_counter()
        with RunLogWriter(Path(tmp) / "decoded.mcap") as decoded:
            for topic, time_ns, message in iter_messages(log_path):
                decoded.write(topic, message, time_ns)
        decoded_copy_s = time.perf_counter() - t0
        seed_everything(cfg.seed + 1)
        env = make_env(cfg, num_envs=min(cfg.eval.num_envs, trials), device="cpu", eval_mode=True)
        actor, _ = load_policy(cfg, env, checkpoint, "cpu")
        t0 = time.perf_counter()
        log = RunLogWriter(log_path, append=True)
        copy_s = time.perf_counter() - t0
        try:
            t0 = time.perf_counter()
            run_evaluation(env, lambda obs: actor(obs), trials, cfg, recorder=log, progress=False)
            recorded_s = time.perf_counter() - t0
        finally:
            log.close()
    return copy_s, decoded_copy_s, recorded_s

if __name__ == "__main__":
    main()
