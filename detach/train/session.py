"""Composition root of a run: config -> env -> models -> PPO+AMP -> run folder.

`train_and_evaluate` trains a run folder's config (or resumes it from its latest checkpoint)
and then evaluates it; `evaluate_run` evaluates a checkpoint on the run's task or another one
(the paper's environment-generalisation experiment: train on LH1, evaluate on LH2/LH3).
"""

from __future__ import annotations

import dataclasses
import random
from pathlib import Path
from typing import Sequence

import numpy as np
import torch

from detach.config import load_task
from detach.config_schema import RunConfig
from detach.envs.lh_env import LHEnv, make_env
from detach.eval.episodes import record_scene, run_evaluation
from detach.models.losses import combine_aux_losses
from detach.models.factory import DEFAULT_OBS_GROUPS, build_actor_critic, rsl_rl_model_cfgs
from detach.motion import default_motion_lib
from detach.runs.folder import RunFolder, atomic_write_json
from detach.runs.mcap_log import RunLogWriter
from detach.train.motion_bridge import amp_part_indices, amp_reference_sampler, reset_reference_sampler
from detach.train.runner import DetachRunner
from detach.train.schedule import stage_lengths


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def train_cfg_dict(cfg: RunConfig, env: LHEnv) -> dict:
    """rsl-rl-lib's train_cfg for this run (algorithm = our AmpPPO)."""
    t, amp = cfg.train, cfg.train.amp
    actor, critic = rsl_rl_model_cfgs(cfg.model, env.obs_spec)
    if len(cfg.model.critic_objectives) <= 1:
        critic.pop("value_objectives", None)
    amp_cfg = dataclasses.asdict(amp)
    amp_cfg["task_specific"] = cfg.env.task_specific_discrimination
    if amp.body_parts:
        amp_cfg["parts"] = amp_part_indices(amp.body_parts, cfg.env.amp_obs_steps)
    return {
        "num_steps_per_env": t.num_steps_per_env, "save_interval": t.save_interval,
        "obs_groups": {k: list(v) for k, v in DEFAULT_OBS_GROUPS.items()},
        "algorithm": {"class_name": "detach.train.amp_ppo:AmpPPO",
                      "num_learning_epochs": t.num_learning_epochs,
                      "num_mini_batches": t.num_mini_batches, "clip_param": t.clip_param,
                      "gamma": t.gamma, "lam": t.lam, "value_loss_coef": t.value_loss_coef,
                      "entropy_coef": t.entropy_coef, "learning_rate": t.learning_rate,
                      "max_grad_norm": t.max_grad_norm, "schedule": t.schedule,
                      "desired_kl": t.desired_kl, "amp_cfg": amp_cfg},
        "actor": actor, "critic": critic,
    }


def _stage_hook(runner: DetachRunner):
    """DETACH's protocol on each DETACH trunk (the actor's, and the critic's unless it shares
    the actor's): snapshot + freeze entering stage 2, unfreeze in 3."""
    models = [m for m in (runner.alg.actor, runner.alg.critic)
              if hasattr(m, "freeze_encoders") and m.owns_trunk]

    def on_stage(stage: str) -> None:
        print(f"stage: {stage}", flush=True)
        for m in models:
            if stage == "fusion":
                m.snapshot_encoders()
                m.freeze_encoders()
            elif stage in ("pretrain", "joint"):
                m.unfreeze_encoders()

    return on_stage, models


def build_runner(cfg: RunConfig, run: RunFolder | None, device: str,
                 log: RunLogWriter | None = None, progress: bool = True
                 ) -> tuple[LHEnv, DetachRunner]:
    if cfg.train.torch_threads > 0:
        torch.set_num_threads(cfg.train.torch_threads)
    seed_everything(cfg.seed)
    env = make_env(cfg, device=device)
    print(env.describe(), flush=True)
    lib = default_motion_lib(device="cpu")
    env.set_reference_sampler(reset_reference_sampler(lib))
    stages = stage_lengths(cfg.train.stages, cfg.train.max_iterations) \
        if cfg.model.kind == "detach" else [("ppo", cfg.train.max_iterations)]
    runner = DetachRunner(env, train_cfg_dict(cfg, env), device=device, schedule=stages,
                          checkpoint_dir=run.checkpoints if run else None, log=log,
                          progress=progress)
    alg = runner.alg
    if alg.amp_enabled:
        alg.reference_sampler = amp_reference_sampler(
            lib, cfg.env.amp_obs_steps, env.dt, cfg.env.task_specific_discrimination, device)
    on_stage, detach_models = _stage_hook(runner)
    runner.on_stage = on_stage
    if detach_models:
        def aux_loss(obs, stage: str):
            """Weighted loss of the stage on each DETACH trunk; every term logged per stage."""
            parts = {}
            total = torch.zeros((), device=device)
            if stage == "pretrain":  # no PPO update normalises the inputs in this stage
                alg.actor.update_normalization(obs)
                alg.critic.update_normalization(obs)
            for name, model in zip(("actor", "critic"), detach_models):
                terms = model.aux_losses(obs)
                loss = combine_aux_losses(terms, stage, model.cfg.regularizers)
                total = total + loss
                parts[f"aux/{stage}/{name}/total"] = float(loss.detach())
                parts.update({f"aux/{stage}/{name}/{k}": float(v.detach())
                              for k, v in terms.items()})
            return total, parts

        alg.aux_loss_fn = aux_loss
    return env, runner


def train_and_evaluate(run: RunFolder, resume: bool, eval_tasks: Sequence[Path] = (),
                       trials: int | None = None, evaluate: bool = True,
                       device: str | None = None) -> None:
    cfg = run.config()
    device = device or cfg.device
    log = RunLogWriter(run.log_path, append=resume)
    try:
        env, runner = build_runner(cfg, run, device, log)
        start = 0
        if resume:
            checkpoint = run.latest_checkpoint()
            start = runner.load_checkpoint(checkpoint)
            print(f"resumed from {checkpoint.name}: continuing at iteration {start}", flush=True)
        else:
            log.log_scene(record_scene(env, cfg))
        runner.on_iteration = lambda it, _m: run.set_state("running", iteration=it + 1)
        runner.learn(cfg.train.max_iterations)
    finally:
        log.close()
    if evaluate:
        evaluate_run(run, None, None, trials, device)
        for task in eval_tasks:
            evaluate_run(run, task, None, trials, device)


def eval_config(cfg: RunConfig, task_path: Path | None) -> RunConfig:
    """The run's config with another task swapped in (sim/env/model settings unchanged)."""
    if task_path is None:
        return cfg
    return dataclasses.replace(cfg, task=load_task(task_path), task_name=Path(task_path).stem)


def evaluate_run(run: RunFolder, task_path: Path | None, checkpoint: Path | None,
                 trials: int | None, device: str | None = None, record: bool = True) -> Path:
    """Evaluate the policy; writes eval.json (own task) or eval_<task>.json (another task).

    On the run's own task (and with `record`) the scene and env 0's first episode go to
    log.mcap; never pass record=True while another process still writes that log."""
    train_cfg = run.config()
    cfg = eval_config(train_cfg, task_path)
    device = device or cfg.device
    checkpoint = checkpoint or run.latest_checkpoint()
    trials = trials or cfg.eval.trials
    seed_everything(cfg.seed + 1)
    env = make_env(cfg, num_envs=min(cfg.eval.num_envs, trials), device=device, eval_mode=True)
    state = torch.load(checkpoint, map_location=device, weights_only=False)
    actor, _critic = build_actor_critic(cfg.model, env.obs_spec, env.get_observations(),
                                        num_actions=env.num_actions)
    actor.load_state_dict(state["actor_state_dict"])
    actor.to(device).eval()
    own = cfg.task_name == train_cfg.task_name
    log = RunLogWriter(run.log_path, append=True) if own and record else None
    try:
        result = run_evaluation(env, lambda obs: actor(obs), trials, cfg, log=log,
                                episode_id=max(int(state.get("iter", 0)), 0))
    finally:
        if log is not None:
            log.close()
    result.update(task=cfg.task_name, trained_on=train_cfg.task_name, model=cfg.model_name,
                  seed=cfg.seed, checkpoint=str(checkpoint.relative_to(run.path))
                  if checkpoint.is_relative_to(run.path) else str(checkpoint),
                  iteration=int(state.get("iter", -1)))
    path = run.eval_path if own else run.path / f"eval_{cfg.task_name}.json"
    atomic_write_json(path, result)
    lh = result["lh_success"]
    print(f"evaluation on {cfg.task_name}: LH success {lh['rate']:.2f} "
          f"[{lh['ci'][0]:.2f}, {lh['ci'][1]:.2f}] over {result['trials']} trials; "
          + ", ".join(f"{s['skill']} {s['rate']:.2f}" for s in result["subtasks"]), flush=True)
    return path
