"""GPU check: what the warp backend buys on this machine, in at most ~10 minutes, side by side.

    python benchmarks/gpu_check.py [--device cuda] [--out gpu_check] [--budget 600]
    python benchmarks/gpu_check.py --device cpu --ns 8 --env-n 8 --ppo-n 8 --ppo-steps 4 --budget 120  # smoke

Sections (each one line of the Markdown table and one entry of the JSON):
1. raw physics: control steps/s (`sim.substeps` physics steps each) of the LH3 humanoid scene
   at each N of `--ns`: the warp backend on `--device` vs `mujoco.batch` on all CPU cores of
   this machine, same model (sleep off for both), constant controls;
2. env: `LHEnv.step` control steps/s at `--env-n` with uniform random actions (warp);
3. PPO: seconds per iteration at `--ppo-n` envs x `--ppo-steps` steps for `mlp` and `detach`
   on the humanoid LH1 (warp, everything on `--device`), after one warm-up iteration;
4. learning: the puppet-Follow task (mlp, warp) trained for the rest of `--budget`; its reward
   and Follow success per iteration.

Writes `<out>/gpu_check.json` and `<out>/gpu_check.md` (device name, versions, figures) and
prints the Markdown; the JSON is rewritten after each section, so a run stopped early keeps what
it measured. A section that fails is reported (its error in the JSON and the Markdown) and the
next one runs; if capturing a CUDA graph fails, the step is measured again with
`sim.cuda_graph=false` and the report says so. The first warp section includes compiling the
kernels (reported apart: `compile_s`); with a warm kernel cache it takes seconds.
"""

from __future__ import annotations

import argparse
import dataclasses
import json
import os
import platform
import time
import traceback
from pathlib import Path

import mujoco
import torch
from mujoco import batch as mjbatch

ROOT = Path(__file__).resolve().parents[1]
TASKS = ROOT / "configs" / "tasks"


def _sync(device: torch.device) -> None:
    if device.type == "cuda":
        torch.cuda.synchronize(device)


CUDA_GRAPH = {"on": True}
"""Whether the warp sections capture CUDA graphs: off once a capture has failed."""


def _cfg(task: str, model: str, overrides: list[str]):
    from detach import resolve_run

    graph = f"sim.cuda_graph={'true' if CUDA_GRAPH['on'] else 'false'}"
    return resolve_run(TASKS / f"{task}.yaml", model, ["sim.backend=warp", graph, *overrides])


def raw_physics(ns: list[int], device: torch.device, seconds: float) -> list[dict]:
    """Control steps/s of the LH3 humanoid scene: warp on `device` vs mujoco.batch (all cores)."""
    from detach import make_backend, make_character
    from scene_builder.assets import ensure_assets
    from scene_builder.scene import compile_scene

    cfg = _cfg("lh3", "mlp", ["env.character=humanoid"])
    ensure_assets(cfg.task)
    model, _ = compile_scene(cfg.task, make_character("humanoid"), cfg.sim)
    sub = cfg.sim.substeps
    rows = []
    for n in ns:
        t0 = time.perf_counter()
        ctrl = torch.zeros(n, model.nu, device=device)
        try:
            be = make_backend(dataclasses.replace(cfg.sim, cuda_graph=CUDA_GRAPH["on"]), model, n, device)
            be.step(ctrl, sub)  # compile (first N) and capture the CUDA graph
            be.step(ctrl, sub)  # replay it once
            _sync(device)
        except Exception:
            if not CUDA_GRAPH["on"] or device.type != "cuda":
                raise
            traceback.print_exc()
            print("gpu_check: the CUDA graph failed; measuring with sim.cuda_graph=false from here", flush=True)
            CUDA_GRAPH["on"] = False
            be = make_backend(dataclasses.replace(cfg.sim, cuda_graph=False), model, n, device)
            be.step(ctrl, sub)
            _sync(device)
        compile_s = time.perf_counter() - t0
        warp_sps = _rate(lambda: be.step(ctrl, sub), n, device, seconds / 2)
        be = None  # free the worlds before the CPU run (the lambda above has run)
        cpu = mjbatch.Batch(model, n, nthread=0, persistent=True)
        cpu.forward()
        cpu_sps = _rate(lambda: cpu.step(nstep=sub), n, torch.device("cpu"), seconds / 2)
        rows.append({"n": n, "warp_steps_per_s": warp_sps, "cpu_steps_per_s": cpu_sps,
                     "cpu_threads": cpu.nthread, "speedup": warp_sps / cpu_sps, "compile_s": compile_s,
                     "cuda_graph": CUDA_GRAPH["on"] and device.type == "cuda"})
        print(f"raw N={n}: warp {warp_sps:.0f}, mujoco.batch {cpu_sps:.0f} control steps/s", flush=True)
    return rows


def _rate(step, n: int, device: torch.device, seconds: float) -> float:
    """Control steps/s of all n worlds: repeat `step` for about `seconds` (at least 3 times)."""
    step()
    _sync(device)
    count, t0 = 0, time.perf_counter()
    while count < 3 or time.perf_counter() - t0 < seconds:
        step()
        count += 1
        if count % 10 == 0:
            _sync(device)
    _sync(device)
    return n * count / (time.perf_counter() - t0)


def env_rate(n: int, device: torch.device, seconds: float) -> dict:
    from detach import make_env

    env = make_env(_cfg("lh3", "mlp", ["env.character=humanoid"]), num_envs=n, device=device, verbose=False)
    gen = torch.Generator(device=device).manual_seed(0)

    def step():
        env.step(torch.rand(n, env.num_actions, generator=gen, device=device) * 2 - 1)

    sps = _rate(step, n, device, seconds)
    print(f"env N={n}: {sps:.0f} control steps/s", flush=True)
    return {"n": n, "env_steps_per_s": sps}


def ppo_iteration(model: str, n: int, steps: int, device: torch.device, iterations: int = 2) -> dict:
    from detach import build_runner

    cfg = _cfg("lh1", model, ["env.character=humanoid", f"sim.num_envs={n}", f"train.num_steps_per_env={steps}",
                              f"train.max_iterations={iterations + 1}"])
    cfg = dataclasses.replace(cfg, device=str(device))
    _env, runner = build_runner(cfg, None, str(device), log=None, progress=False)
    stamps = [time.perf_counter()]
    runner.on_iteration = lambda it, m: stamps.append(time.perf_counter())
    runner.learn(iterations + 1)
    times = [b - a for a, b in zip(stamps, stamps[1:])]
    s = min(times[1:]) if len(times) > 1 else times[0]
    print(f"PPO {model}: {s:.2f} s per iteration ({n} x {steps})", flush=True)
    return {"model": model, "n": n, "steps": steps, "s_per_iteration": s, "first_s": times[0]}


def _metric(metrics: dict, *names: str) -> float | None:
    """The first metric named (or ending with) one of names: the log's names may change."""
    for name in names:
        for key, value in metrics.items():
            if key == name or key.endswith("/" + name):
                return float(value)
    return None


def learning_curve(n: int, steps: int, device: torch.device, seconds: float) -> dict:
    from detach import build_runner

    cfg = _cfg("follow", "mlp", ["env.character=puppet", f"sim.num_envs={n}", f"train.num_steps_per_env={steps}",
                                 "train.max_iterations=100000"])
    cfg = dataclasses.replace(cfg, device=str(device))
    _env, runner = build_runner(cfg, None, str(device), log=None, progress=False)
    curve: list[dict] = []
    t0 = time.perf_counter()

    class Done(Exception):
        pass

    def on_iteration(it: int, m: dict) -> None:
        curve.append({"iteration": it, "minutes": (time.perf_counter() - t0) / 60,
                      "reward": _metric(m, "reward/mean", "Train/mean_reward"), "follow": _metric(m, "0_follow")})
        if time.perf_counter() - t0 > seconds:
            raise Done

    runner.on_iteration = on_iteration
    try:
        runner.learn(100000)
    except Done:
        pass
    last = curve[-1] if curve else {}
    print(f"learning: {len(curve)} iterations in {last.get('minutes', 0):.1f} min, reward {last.get('reward')}",
          flush=True)
    return {"n": n, "steps": steps, "curve": curve}


def device_name(device: torch.device) -> str:
    if device.type == "cuda":
        return torch.cuda.get_device_name(device)
    return f"CPU ({platform.processor() or platform.machine()}, {os.cpu_count()} cores; warp's CPU device)"


def markdown(report: dict) -> str:
    lines = [f"# GPU check: {report['device_name']}", "",
             f"{report['date']}, {report['versions']}, {os.cpu_count()} CPU cores, "
             f"{report['wall_s'] / 60:.1f} min in all.", "",
             "| measure | N | warp | mujoco.batch (all cores) | ratio |", "| --- | --- | --- | --- | --- |"]
    for r in report.get("raw", []):
        lines.append(f"| raw physics, LH3 humanoid, control steps/s | {r['n']} | {r['warp_steps_per_s']:.0f} | "
                     f"{r['cpu_steps_per_s']:.0f} ({r['cpu_threads']} threads) | {r['speedup']:.1f}x |")
    if report.get("env"):
        e = report["env"]
        lines.append(f"| env control steps/s, random actions | {e['n']} | {e['env_steps_per_s']:.0f} | | |")
    for p in report.get("ppo", []):
        lines.append(f"| PPO iteration, {p['model']}, s ({p['n']} x {p['steps']}) | {p['n']} | "
                     f"{p['s_per_iteration']:.2f} | | |")
    lc = report.get("learning")
    if lc and lc["curve"]:
        lines += ["", f"Puppet Follow (mlp, {lc['n']} x {lc['steps']}) learning curve:", "",
                  "| iteration | minutes | reward | follow success |", "| --- | --- | --- | --- |"]
        curve = lc["curve"]
        for row in curve[:: max(len(curve) // 10, 1)] + ([curve[-1]] if len(curve) > 1 else []):
            fmt = lambda v: "" if v is None else f"{v:.3f}"  # noqa: E731
            lines.append(f"| {row['iteration']} | {row['minutes']:.1f} | {fmt(row['reward'])} | {fmt(row['follow'])} |")
    if report.get("raw"):
        graph = "CUDA graph per control step" if report["raw"][-1]["cuda_graph"] else "no CUDA graph"
        lines += ["", f"Kernel compile + first step: {report['raw'][0]['compile_s']:.0f} s; {graph}."]
    for name, error in report.get("errors", {}).items():
        lines += ["", f"Section {name} failed: {error}"]
    return "\n".join(lines) + "\n"


def _section(report: dict, name: str, out: Path, measure) -> None:
    """report[name] = measure(), or its error under report['errors']; then the JSON, so far."""
    t0 = time.perf_counter()
    print(f"gpu_check: {name} ...", flush=True)
    try:
        report[name] = measure()
    except Exception as exc:  # one failed section must not lose the others' figures
        traceback.print_exc()
        report.setdefault("errors", {})[name] = f"{type(exc).__name__}: {exc}"[:2000]
    print(f"gpu_check: {name} took {time.perf_counter() - t0:.0f} s", flush=True)
    out.mkdir(parents=True, exist_ok=True)
    (out / "gpu_check.json").write_text(json.dumps(report, indent=1))


def main(argv: list[str] | None = None) -> int:
    ap = argparse.ArgumentParser(description=__doc__.splitlines()[0])
    ap.add_argument("--device", default="cuda")
    ap.add_argument("--out", type=Path, default=Path("gpu_check"))
    ap.add_argument("--budget", type=float, default=600.0, help="seconds in all (the learning curve gets the rest)")
    ap.add_argument("--ns", type=int, nargs="+", default=[1024, 4096], help="raw physics world counts")
    ap.add_argument("--env-n", type=int, default=4096)
    ap.add_argument("--ppo-n", type=int, default=4096)
    ap.add_argument("--ppo-steps", type=int, default=32)
    ap.add_argument("--models", nargs="*", default=["mlp", "detach"])
    ap.add_argument("--seconds", type=float, default=10.0, help="timing per raw / env measurement")
    args = ap.parse_args(argv)
    from detach import warp_available

    why = warp_available()
    if why is not None:
        raise SystemExit(f"gpu_check: {why}")
    device = torch.device(args.device)
    t0 = time.perf_counter()
    import warp

    versions = f"mujoco {mujoco.__version__}, warp {warp.config.version}, torch {torch.__version__}"
    report: dict = {"date": time.strftime("%Y-%m-%d %H:%M %Z"), "device": str(device),
                    "device_name": device_name(device), "versions": versions}
    _section(report, "raw", args.out, lambda: raw_physics(args.ns, device, args.seconds))
    _section(report, "env", args.out, lambda: env_rate(args.env_n, device, args.seconds))
    report["ppo"] = []
    for model in args.models:
        _section(report, f"ppo_{model}", args.out, lambda: ppo_iteration(model, args.ppo_n, args.ppo_steps, device))
        if f"ppo_{model}" in report:
            report["ppo"].append(report.pop(f"ppo_{model}"))
    rest = args.budget - (time.perf_counter() - t0)
    if rest > 0:
        _section(report, "learning", args.out, lambda: learning_curve(args.ppo_n, args.ppo_steps, device, rest))
    report["wall_s"] = time.perf_counter() - t0
    args.out.mkdir(parents=True, exist_ok=True)
    (args.out / "gpu_check.json").write_text(json.dumps(report, indent=1))
    text = markdown(report)
    (args.out / "gpu_check.md").write_text(text)
    print(text)
    return 0


if __name__ == "__main__":
    raise SystemExit(main())
