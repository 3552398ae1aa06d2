"""Composition root of a run folder: assets -> training (`detach.train.setup`) -> evaluation.

`train_and_evaluate` trains a run folder with the config it was created (or resumed) with, in
memory: the process that wrote config.yaml neither reads nor validates it again (a new process,
evaluating or resuming a stored run, reads it once), and then evaluates it; `evaluate_run`
evaluates a checkpoint on the run's task or another one (the paper's environment-generalisation
experiment: train on LH1, evaluate on LH2/LH3). Missing assets are built before any environment
exists, with a visible progress line.
"""

from __future__ import annotations

import dataclasses
import json
from pathlib import Path
from typing import Sequence

import yaml

from detach.config import load_run_config, load_task
from detach.config.validate import to_plain
from detach.config.schema import RunConfig
from detach.envs.lh_env import make_env
from detach.eval.aids import run_aids
from detach.eval.episodes import TrainingEpisodes, run_evaluation
from detach.eval.trial_sets import TrialSetError, trial_seed
from detach.eval.scene import scene_message
from detach.runfolder.eval_result import EvalResult
from detach.runfolder.names import checkpoint_iteration, eval_file, policy_eval_file
from detach.runs.checkpoint_choice import select_checkpoint
from detach.runfolder.atomic import atomic_write_json, atomic_write_text
from detach.runfolder.folder import RunFolder, read_eval
from detach.runs.mcap_log import RunLogWriter
from detach.runs.policy import load_policy
from detach.runs.provenance import write_provenance
from detach.runs.start_choice import choose_action_means
from detach.train.clip_clone import start_from_clone
from detach.train.checkpoints import CheckpointError, run_policy_checkpoint
from detach.train.setup import (
    apply_torch_threads, build_runner, load_initial_weights, prepare_assets, seed_everything, train_cfg_dict,
)


def train_and_evaluate(run: RunFolder, cfg: RunConfig, resume: bool, eval_tasks: Sequence[Path] = (),
                       trials: int | None = None, evaluate: bool = True,
                       device: str | None = None, checkpoint: Path | None = None,
                       test_offset: int | None = None) -> None:
    """Train `cfg`, the config the run folder records (or resume from `checkpoint`, default the
    newest), then evaluate (on the test trials of `test_offset` when given: a sweep cell's final
    evaluation)."""
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
            elif cfg.train.clone_start.rounds:
                print(start_from_clone(runner, cfg, run.path, log=lambda line: print(line, flush=True)), flush=True)
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
        evaluate_run(run, None, None, trials, device, test_offset=test_offset, train_cfg=cfg)
        for task in eval_tasks:
            evaluate_run(run, task, None, trials, device, test_offset=test_offset, train_cfg=cfg)


def write_agent_params(run: RunFolder, cfg: RunConfig, env) -> Path:
    """params/agent.yaml: the run's rsl-rl train config as plain YAML, so that stock rsl-rl
    code loads its checkpoints (`OnPolicyRunner(env, cfg, None, device).load(path)` with
    `detach.train.amp_ppo:AmpPPO` as the algorithm; docs/EXPORT.md)."""
    path = run.agent_params_path
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


def eval_path(run: RunFolder, train_cfg: RunConfig, cfg: RunConfig, trial_set: str = "development") -> Path:
    """Where an evaluation of `cfg` (`eval_config` of the run's `train_cfg`) is written:
    eval.json on the run's own task, eval_<task>.json on another (eval.test.json,
    eval_<task>.test.json on the test trials)."""
    return run.path / eval_file(None if cfg.task_name == train_cfg.task_name else cfg.task_name, trial_set)


def trial_set_of(run: RunFolder, test_offset: int | None) -> str:
    """The trial set an evaluation plays: the test set only for a sweep cell (the tables'
    figures), so that no probe or hand-made run can play or overwrite it."""
    if test_offset is None:
        return "development"
    try:
        cell = run.status().cell
    except (OSError, ValueError):
        cell = None
    if cell is None:
        raise TrialSetError(f"{run.path}: the test trials are played only for a sweep's cells (detach-run sweep); "
                            "evaluate other runs on the development trials (without --test-trials)")
    return "test"


def smaller_evaluation(run: RunFolder, task_path: Path | None, trials: int | None,
                       test_offset: int | None = None) -> str | None:
    """Why evaluating with `trials` would replace a larger evaluation of the same task (None
    when it would not): a quick check must not overwrite the 100-trial figure of a table."""
    train_cfg = run.config()
    cfg = eval_config(train_cfg, task_path)
    trials = cfg.eval.trials if trials is None else trials
    path = eval_path(run, train_cfg, cfg, trial_set_of(run, test_offset))
    try:
        old = read_eval(path) if path.exists() else None
    except (OSError, ValueError):
        return None  # unreadable: nothing worth keeping
    if old is None or old.trials <= trials:
        return None
    return (f"{path} holds a {old.trials}-trial evaluation of {old.checkpoint}; this {trials}-trial one would "
            "replace it (pass --replace to do so)")


def evaluate_run(run: RunFolder, task_path: Path | None, checkpoint: Path | None,
                 trials: int | None, device: str | None = None, record: bool = True,
                 test_offset: int | None = None, train_cfg: RunConfig | None = None) -> Path:
    """Evaluate the policy; writes eval.json (own task) or eval_<task>.json (another task),
    on the development trials, or with `test_offset` (a sweep cell only) on the test trials,
    into eval.test.json / eval_<task>.test.json.

    On the run's own task (and with `record`) the scene and every trial go to log.mcap;
    never pass record=True while another process still writes that log. `train_cfg`: the run's
    config when this process holds it already (None: read from config.yaml)."""
    trial_set = trial_set_of(run, test_offset)
    train_cfg = train_cfg or run.config()
    cfg = eval_config(train_cfg, task_path)
    checkpoint = checkpoint or run_policy_checkpoint(run.path, device or cfg.device)
    if checkpoint is None:
        raise CheckpointError("no readable checkpoint to evaluate", str(run.checkpoints))
    own = cfg.task_name == train_cfg.task_name
    log = RunLogWriter(run.log_path, append=True) if own and record else None
    try:
        result = _evaluate(cfg, train_cfg, checkpoint, trials, device, trial_set, test_offset, log)
    finally:
        if log is not None:
            log.close()
    result.checkpoint = str(checkpoint.relative_to(run.path)) if checkpoint.is_relative_to(run.path) \
        else str(checkpoint)
    path = eval_path(run, train_cfg, cfg, trial_set)
    atomic_write_json(path, result.to_json())
    return path


def evaluate_policy_file(policy: Path, task_path: Path | None, seed: int | None, trials: int | None,
                         device: str | None = None, test_offset: int | None = None) -> Path:
    """Evaluate an exported policy (`detach-run export --format policy`) without its run
    folder: the run's config from the file beside it, seed `seed` (default the run's). Writes
    <file>.eval_<task>_s<seed>.json (`.test.json` on the test trials, which only a sweep cell's
    policy may play) beside the policy."""
    info = read_policy_info(policy)
    train_cfg = load_run_config(policy.parent / str(info["config"]))
    if seed is not None:
        train_cfg = dataclasses.replace(train_cfg, seed=int(seed))
    if test_offset is not None and not info.get("cell"):
        raise TrialSetError(f"{policy}: the test trials are played only for a sweep cell's policy (its JSON "
                            "names no cell); evaluate it on the development trials (without --test-trials)")
    trial_set = "development" if test_offset is None else "test"
    cfg = eval_config(train_cfg, task_path)
    result = _evaluate(cfg, train_cfg, policy, trials, device, trial_set, test_offset, None)
    result.checkpoint = policy.name
    path = policy.with_name(policy_eval_file(policy.name, cfg.task_name, cfg.seed, trial_set))
    atomic_write_json(path, result.to_json())
    return path


def read_policy_info(policy: Path) -> dict:
    """The JSON beside an exported policy, checked to be a `--format policy` export."""
    layout = policy.with_name(policy.name.removesuffix(".pt") + ".json")
    try:
        info = json.loads(layout.read_text())
    except (OSError, ValueError) as exc:
        raise CheckpointError(f"cannot read the policy's description {layout.name} ({exc})", str(policy)) from None
    if not isinstance(info, dict) or info.get("format") != "policy" or not isinstance(info.get("config"), str):
        raise CheckpointError(f"{layout.name} does not describe a `detach-run export --format policy` file",
                              str(policy))
    return info


def _evaluate(cfg: RunConfig, train_cfg: RunConfig, checkpoint: Path, trials: int | None, device: str | None,
              trial_set: str, test_offset: int | None, log: RunLogWriter | None) -> EvalResult:
    """Play `trials` trials of `cfg`'s task (the set `trial_set`) with the checkpoint's
    actor under mean actions; the result names its model, seed, trials and aids."""
    device = device or cfg.device
    trials = cfg.eval.trials if trials is None else trials
    prepare_assets(cfg.task)
    apply_torch_threads(cfg)
    seed_everything(cfg.seed + 1)
    env_seed = trial_seed(cfg.seed, trial_set, test_offset)
    env = make_env(cfg, num_envs=min(cfg.eval.num_envs, trials), device=device, eval_mode=True, seed=env_seed)
    actor, state = load_policy(cfg, env, checkpoint, device)
    result = run_evaluation(env, lambda obs: actor(obs), trials, cfg, recorder=log,
                            episode_id=max(int(state.get("iter", 0)), 0))
    result.trained_on, result.model, result.seed = train_cfg.task_name, cfg.model_name, cfg.seed
    result.iteration = int(state.get("iter", -1))
    result.trial_set, result.trial_seed, result.aids = trial_set, env_seed, run_aids(train_cfg)
    mean, chain = result.lh_mean, result.lh_chain
    print(f"evaluation on {cfg.task_name} over {result.trials} {trial_set} trials: "
          + ", ".join(f"{s.skill} {s.rate:.2f}" for s in result.subtasks)
          + f"; LH (mean of subtasks) {mean.rate:.2f} [{mean.ci[0]:.2f}, {mean.ci[1]:.2f}], "
          f"LH (whole chain) {chain.rate:.2f} [{chain.ci[0]:.2f}, {chain.ci[1]:.2f}]", flush=True)
    return result
