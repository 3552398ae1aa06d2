"""Composition root of a run folder: assets -> training (`detach.train.setup`) -> evaluation.

`train_and_evaluate` trains a run folder's config (or resumes it from its latest checkpoint)
and then evaluates it; `evaluate_run` evaluates a checkpoint on the run's task or another one
(the paper's environment-generalisation experiment: train on LH1, evaluate on LH2/LH3).
Missing assets are built before any environment exists, with a visible progress line.
"""

from __future__ import annotations

import dataclasses
from pathlib import Path
from typing import Sequence

import yaml

from detach.config import load_task
from detach.config_validate import to_plain
from detach.config_schema import RunConfig
from detach.envs.lh_env import make_env
from detach.eval.episodes import TrainingEpisodes, run_evaluation
from detach.eval.scene import scene_message
from detach.run_contract import AGENT_PARAMS_FILE, checkpoint_iteration, eval_file
from detach.runs.checkpoint_choice import select_checkpoint
from detach.runs.folder import RunFolder, atomic_write_json, atomic_write_text, read_eval
from detach.runs.mcap_log import RunLogWriter
from detach.runs.policy import load_policy
from detach.runs.provenance import write_provenance
from detach.runs.start_choice import choose_action_means
from detach.train.checkpoints import CheckpointError
from detach.train.setup import (
    apply_torch_threads, build_runner, load_initial_weights, prepare_assets, seed_everything, train_cfg_dict,
)


def train_and_evaluate(run: RunFolder, resume: bool, eval_tasks: Sequence[Path] = (),
                       trials: int | None = None, evaluate: bool = True,
                       device: str | None = None, checkpoint: Path | None = None) -> None:
    """Train (or resume from `checkpoint`, default the newest), then evaluate."""
    cfg = run.config()
    device = device or cfg.device
    checkpoint = (checkpoint or run.latest_checkpoint()) if resume else None
    log = RunLogWriter(run.log_path, append=resume,
                       metrics_until=checkpoint_iteration(checkpoint.name) if checkpoint else None)
    try:
        write_provenance(run, device, resumed=resume)
        env, runner = build_runner(cfg, run.checkpoints, device, log)
        write_agent_params(run, cfg, env)
        runner.model_name, runner.model_kind = cfg.model_name, cfg.model.kind
        runner.keep_last, runner.keep_every = cfg.train.keep_checkpoints.last, cfg.train.keep_checkpoints.every
        start = 0
        if resume:
            run.clear_selection()
            start = runner.load_checkpoint(checkpoint)
            print(f"resumed from {checkpoint.name}: continuing at iteration {start}", flush=True)
        else:
            if cfg.train.init_from:
                print(load_initial_weights(runner, cfg), flush=True)
                if cfg.train.init_action_mean_choices:
                    print(choose_action_means(runner.alg.actor, cfg, device), flush=True)
            log.log_scene(scene_message(env, cfg))
        runner.on_iteration = lambda it, _m: run.set_state("running", iteration=it + 1)
        runner.episode_recorder = TrainingEpisodes(log)
        runner.learn(cfg.train.max_iterations, init_at_random_ep_len=cfg.train.init_at_random_ep_len)
    finally:
        log.close()
    if cfg.train.select_checkpoint_trials:
        del env, runner  # the validation env takes their place
        print(select_checkpoint(run, cfg, device), flush=True)
    if evaluate:
        evaluate_run(run, None, None, trials, device)
        for task in eval_tasks:
            evaluate_run(run, task, None, trials, device)


def write_agent_params(run: RunFolder, cfg: RunConfig, env) -> Path:
    """params/agent.yaml: the run's rsl-rl train config as plain YAML, so that stock rsl-rl
    code loads its checkpoints (`OnPolicyRunner(env, cfg, None, device).load(path)` with
    `detach.train.amp_ppo:AmpPPO` as the algorithm; docs/EXPORT.md)."""
    path = run.path / AGENT_PARAMS_FILE
    params = train_cfg_dict(cfg, env)
    if params["logger"] == "none":  # ours; rsl-rl's own default, used only when it gets a log_dir
        params["logger"] = "tensorboard"
    atomic_write_text(path, yaml.safe_dump(to_plain(params), sort_keys=False))
    return path


def eval_config(cfg: RunConfig, task_path: Path | None) -> RunConfig:
    """The run's config with another task swapped in (sim/env/model settings unchanged)."""
    if task_path is None:
        return cfg
    return dataclasses.replace(cfg, task=load_task(task_path), task_name=Path(task_path).stem)


def eval_path(run: RunFolder, train_cfg: RunConfig, cfg: RunConfig) -> Path:
    """Where an evaluation of `cfg` (`eval_config` of the run's `train_cfg`) is written:
    eval.json on the run's own task, eval_<task>.json on another."""
    return run.path / eval_file(None if cfg.task_name == train_cfg.task_name else cfg.task_name)


def smaller_evaluation(run: RunFolder, task_path: Path | None, trials: int | None) -> str | None:
    """Why evaluating with `trials` would replace a larger evaluation of the same task (None
    when it would not): a quick check must not overwrite the 100-trial figure of a table."""
    train_cfg = run.config()
    cfg = eval_config(train_cfg, task_path)
    trials = cfg.eval.trials if trials is None else trials
    path = eval_path(run, train_cfg, cfg)
    try:
        old = read_eval(path) if path.exists() else None
    except (OSError, ValueError):
        return None  # unreadable: nothing worth keeping
    if old is None or old.trials <= trials:
        return None
    return (f"{path} holds a {old.trials}-trial evaluation of {old.checkpoint}; this {trials}-trial one would "
            "replace it (pass --replace to do so)")


def evaluate_run(run: RunFolder, task_path: Path | None, checkpoint: Path | None,
                 trials: int | None, device: str | None = None, record: bool = True) -> Path:
    """Evaluate the policy; writes eval.json (own task) or eval_<task>.json (another task).

    On the run's own task (and with `record`) the scene and every trial go to log.mcap;
    never pass record=True while another process still writes that log."""
    train_cfg = run.config()
    cfg = eval_config(train_cfg, task_path)
    device = device or cfg.device
    checkpoint = checkpoint or run.policy_checkpoint(device)
    if checkpoint is None:
        raise CheckpointError("no readable checkpoint to evaluate", str(run.checkpoints))
    trials = cfg.eval.trials if trials is None else trials
    prepare_assets(cfg.task)
    apply_torch_threads(cfg)
    seed_everything(cfg.seed + 1)
    env = make_env(cfg, num_envs=min(cfg.eval.num_envs, trials), device=device, eval_mode=True)
    actor, state = load_policy(cfg, env, checkpoint, device)
    own = cfg.task_name == train_cfg.task_name
    log = RunLogWriter(run.log_path, append=True) if own and record else None
    try:
        result = run_evaluation(env, lambda obs: actor(obs), trials, cfg, recorder=log,
                                episode_id=max(int(state.get("iter", 0)), 0))
    finally:
        if log is not None:
            log.close()
    result.trained_on, result.model, result.seed = train_cfg.task_name, cfg.model_name, cfg.seed
    result.checkpoint = str(checkpoint.relative_to(run.path)) if checkpoint.is_relative_to(run.path) \
        else str(checkpoint)
    result.iteration = int(state.get("iter", -1))
    path = eval_path(run, train_cfg, cfg)
    atomic_write_json(path, result.to_json())
    mean, chain = result.lh_mean, result.lh_chain
    print(f"evaluation on {cfg.task_name} over {result.trials} trials: "
          + ", ".join(f"{s.skill} {s.rate:.2f}" for s in result.subtasks)
          + f"; LH (mean of subtasks) {mean.rate:.2f} [{mean.ci[0]:.2f}, {mean.ci[1]:.2f}], "
          f"LH (whole chain) {chain.rate:.2f} [{chain.ci[0]:.2f}, {chain.ci[1]:.2f}]", flush=True)
    return path
