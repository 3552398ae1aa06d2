"""A start for PPO cloned from the motion clips: the actor fitted to the clips' own hinge
targets, played open-loop from reference-state starts (behaviour cloning).

Why: the humanoid's PPO runs sat in a standing pose (results/humanoid/NOTEBOOK.md); a policy
that starts out stepping like the clips gives PPO a gait to refine instead of one to find.
Each round resets every env of the run's training env at a reference state (`env.init:
random`), remembers the clip and time each env got, and plays the clip's next frames as PD
targets (`pd_actions`) for `steps` control steps, keeping (observation, action) while the
episode lasts and the clip has frames. The actor (its observation normaliser included) is then
fitted by mean squared error; the runner's checkpoint is a start for `train.init_from` (with
`train.critic_warmup_iterations`: its critic is untrained), or a run clones its own start
before its first iteration (`train.clone_start`, `start_from_clone`).
"""

from __future__ import annotations

import dataclasses
import time
from pathlib import Path
from typing import Callable

import torch

from detach.character.actions import pd_actions
from detach.config.schema import RunConfig
from detach.motion.builtin import default_motion_lib
from detach.train.motion_bridge import motion_label_weights, reset_reference_sampler, start_clip_labels
from detach.train.setup import build_runner, load_initial_weights


def clone_clip_start(cfg: RunConfig, out: Path, rounds: int = 60, steps: int = 45, epochs: int = 30,
                     assist: tuple[float, float] = (0.0, 0.0), log: Callable[[str], None] = print) -> dict[str, float]:
    """Clone, write the checkpoint to `out`, and check the clone closed-loop (mean actions,
    150 steps from reference starts, without and with `assist`). Returns the figures logged.
    The actor's observations stay in RAM, in float16 (~10 kB each for the humanoid's Follow:
    60 rounds of 64 envs keep ~1.2 GB)."""
    env, runner = build_runner(cfg, None, "cpu", log=None, progress=False)
    lib = default_motion_lib(device="cpu", skill_weights=motion_label_weights(cfg))
    drawn: dict[str, torch.Tensor] = {}  # the clip and time each env of the latest reset got
    env.set_reference_sampler(reset_reference_sampler(lib, start_clip_labels(cfg), drawn))
    env.world.assist.set(*assist)
    lo, hi, actor = env.character.dof_lo, env.character.dof_hi, runner.alg.actor
    obs_rows, act_rows, t0 = [], [], time.time()
    with torch.no_grad():
        for r in range(rounds):
            obs = env.reset()
            ids, times = drawn["ids"], drawn["times"]
            alive = torch.ones(env.num_envs, dtype=torch.bool)
            for k in range(steps):
                tk = times + (k + 1) * env.dt
                a = pd_actions(lib.state(ids, tk).dof_pos.float(), lo, hi)
                keep = alive & (tk <= lib.clip_length[ids])
                obs_rows.append(obs[keep].select(*actor.obs_groups).to(torch.float16))
                act_rows.append(a[keep])
                obs, _, dones, _ = env.step(a)
                alive &= ~dones.bool()
            if r % 10 == 0 or r == rounds - 1:
                log(f"round {r}: {sum(len(a) for a in act_rows)} pairs, {float(alive.float().mean()):.2f} of the "
                    f"envs still up after {steps} steps, {time.time() - t0:.0f} s")
    obs_all, act_all = torch.cat(obs_rows), torch.cat(act_rows)
    del obs_rows
    for i in range(0, len(obs_all), 4096):
        actor.update_normalization(obs_all[i:i + 4096].to(torch.float32))
    opt = torch.optim.Adam([p for name, p in actor.named_parameters() if "std" not in name], lr=1e-3)
    n, variance = act_all.shape[0], float(act_all.var(0).mean())
    figures = {"pairs": float(n), "action_variance": variance}
    for epoch in range(epochs):
        perm, total = torch.randperm(n), 0.0
        for i in range(0, n, 4096):
            b = perm[i:i + 4096]
            loss = ((actor(obs_all[b].to(torch.float32)) - act_all[b]) ** 2).mean()
            opt.zero_grad()
            loss.backward()
            opt.step()
            total += float(loss.detach()) * len(b)
        figures["mse"] = total / n
        if epoch % 10 == 0 or epoch == epochs - 1:
            log(f"epoch {epoch}: mse {total / n:.5f} (action variance {variance:.5f})")
    out.parent.mkdir(parents=True, exist_ok=True)
    runner.model_name, runner.model_kind = cfg.model_name, cfg.model.kind  # named in the file's infos
    runner.save(str(out))
    log(f"wrote {out}")
    for gains in dict.fromkeys(((0.0, 0.0), tuple(assist))):  # once when the assist is off
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
        key = f"assist_{gains[0]:g}_{gains[1]:g}"
        figures[f"{key}_steps"], figures[f"{key}_walked_m"] = float(end.float().mean()), float(walked.mean())
        log(f"closed loop, assist {gains[0]:g}/{gains[1]:g}: {figures[f'{key}_steps']:.1f} steps before the first "
            f"episode end, {figures[f'{key}_walked_m']:.2f} m walked")
    return figures


CLONE_FILE = "clone_start.pt"
"""Where a run with `train.clone_start` keeps the start it cloned (in its run folder)."""


def start_from_clone(runner, cfg: RunConfig, run_dir: Path, log: Callable[[str], None] = print) -> str:
    """`train.clone_start`: clone a start with the run's own env and model settings (every
    start a reference state, the clips played without the balance assist), write it to
    `run_dir`/CLONE_FILE and load it into `runner` as `train.init_from` would; its critic and
    discriminator are the untrained ones the run had. Returns the log line of the load."""
    c = cfg.train.clone_start
    clone_cfg = dataclasses.replace(cfg, env=dataclasses.replace(cfg.env, init="random"))
    out = Path(run_dir) / CLONE_FILE
    clone_clip_start(clone_cfg, out, c.rounds, c.steps, c.epochs, log=log)
    start = dataclasses.replace(cfg, train=dataclasses.replace(cfg.train, init_from=str(out)))
    return load_initial_weights(runner, start)
