"""Everything a training run is made of: config -> env -> models -> PPO+AMP runner.

`build_runner` builds the task's missing assets (a progress line, before any environment
exists), makes the environment, the motion library's samplers, rsl-rl's runner with our `AmpPPO`, and
DETACH's stage hooks and auxiliary losses. The run folder around it is `detach.runs.session`.
"""

from __future__ import annotations

import math
import random
from pathlib import Path
from typing import Iterator, Sequence

import numpy as np
import torch
from rsl_rl.modules import EmpiricalNormalization

from detach.character import character_class
from detach.config import ConfigError, load_run_config
from detach.config.schema import RunConfig, TaskCfg
from detach.envs.lh_env import LHEnv
from detach.models.factory import DEFAULT_OBS_GROUPS, rsl_rl_model_cfgs
from detach.models.losses import combine_aux_losses
from detach.models.structured import new_parameter_prefixes
from detach.motion import default_motion_lib
from detach.runfolder.folder import RunFolder
from detach.runfolder.names import CONFIG_FILE
from detach.skills import canonical_name
from detach.train.action_bounds import action_bound_loss
from detach.train.checkpoints import CheckpointError, find_init_checkpoint, read_checkpoint
from detach.train.distributed import local_device, rank
from detach.train.motion_bridge import (amp_part_indices, amp_reference_sampler, motion_label_weights,
                                        reset_reference_sampler, start_clip_labels)
from detach.train.runner import DetachRunner, MetricsSink
from detach.train.schedule import stage_lengths
from detach.train.start_library import make_training_env
from detach.train.teachers import load_teachers
from detach.train.trained_actor import default_action_std
from scene_builder.assets import ensure_assets


def prepare_assets(task: TaskCfg) -> None:
    """Build the task's missing assets now (a progress line if there is anything to build), in
    this process: a process pool needs a main module it can re-import, which not every caller
    has, and a task needs a handful of assets (`detach-scene build --jobs N` builds many)."""
    ensure_assets(task, jobs=1, log=lambda line: print(line, flush=True))


def apply_torch_threads(cfg: RunConfig) -> None:
    """torch's CPU threads as `train.torch_threads` says (0: torch's default), for every
    process that runs the run's policy: training, evaluation and play alike. Two 100-trial LH1
    evaluations side by side on 2 cores took 23 min each with torch's default 2 threads beside
    MuJoCo's, and 2.9 min with one thread each (same figures)."""
    if cfg.train.torch_threads > 0:
        torch.set_num_threads(cfg.train.torch_threads)


def seed_everything(seed: int) -> None:
    random.seed(seed)
    np.random.seed(seed)
    torch.manual_seed(seed)


def logger_cfg(cfg: RunConfig) -> str | dict:
    """`train.logger` as rsl-rl's train_cfg["logger"] ("none" is ours: no writer)."""
    if cfg.train.logger == "wandb":
        return {"class_name": "rsl_rl.utils.wandb_log_writer:WandbLogWriter", "project_name": cfg.train.wandb_project}
    return cfg.train.logger


def train_cfg_dict(cfg: RunConfig, env: LHEnv) -> dict:
    """rsl-rl-lib's train_cfg for this run (algorithm = our AmpPPO, typed configs inside)."""
    t, amp = cfg.train, cfg.train.amp
    actor, critic = rsl_rl_model_cfgs(cfg.model, env.obs_spec, default_action_std(cfg))
    parts = amp_part_indices(amp.body_parts, cfg.env.amp_obs_steps) if amp.body_parts else None
    return {
        "num_steps_per_env": t.num_steps_per_env, "save_interval": t.save_interval,
        "check_for_nan": t.check_for_nan, "logger": logger_cfg(cfg),
        "obs_groups": {k: list(v) for k, v in DEFAULT_OBS_GROUPS.items()},
        "algorithm": {"class_name": "detach.train.amp_ppo:AmpPPO",
                      "num_learning_epochs": t.num_learning_epochs,
                      "num_mini_batches": t.num_mini_batches, "clip_param": t.clip_param,
                      "gamma": t.gamma, "lam": t.lam, "value_loss_coef": t.value_loss_coef,
                      "entropy_coef": t.entropy_coef, "learning_rate": t.learning_rate,
                      "max_grad_norm": t.max_grad_norm, "schedule": t.schedule,
                      "use_clipped_value_loss": t.clipped_value_loss,
                      "desired_kl": t.desired_kl, "amp": amp,
                      "task_specific": cfg.env.task_specific_discrimination, "amp_parts": parts,
                      "per_objective_advantage_norm": t.per_objective_advantage_norm},
        "actor": actor, "critic": critic,
    }


def _stage_hook(runner: DetachRunner):
    """DETACH's protocol on each DETACH trunk (the actor's, and the critic's unless it shares
    the actor's): snapshot + freeze entering stage 2, unfreeze in 3."""
    models = [m for m in (runner.alg.actor, runner.alg.critic)
              if hasattr(m, "freeze_encoders") and m.owns_trunk]

    def on_stage(stage: str, resumed: bool = False) -> None:
        print(f"stage: {stage}{' (resumed)' if resumed else ''}", flush=True)
        for m in models:
            if stage == "fusion":
                if not resumed:  # a resumed run's anchors come from its checkpoint
                    m.snapshot_encoders()
                m.freeze_encoders()
            elif stage in ("pretrain", "joint"):
                m.unfreeze_encoders()

    return on_stage, models


def build_runner(cfg: RunConfig, checkpoint_dir: Path | None, device: str, log: MetricsSink | None = None,
                 progress: bool = True) -> tuple[LHEnv, DetachRunner]:
    apply_torch_threads(cfg)
    device = local_device(device)
    seed_everything(cfg.seed + rank())  # torchrun: each rank its own experience
    prepare_assets(cfg.task)
    env = make_training_env(cfg, device=device, seed=cfg.seed + rank())
    print(env.describe(), flush=True)
    lib = default_motion_lib(device="cpu", skill_weights=motion_label_weights(cfg))
    env.set_reference_sampler(reset_reference_sampler(lib, start_clip_labels(cfg)))
    teachers = load_teachers(cfg, env, device)  # before the runner: an oracle teacher adds an observation group
    stages = stage_lengths(cfg.train.stages, cfg.train.max_iterations) \
        if cfg.model.staged else [("ppo", cfg.train.max_iterations)]
    runner = DetachRunner(env, train_cfg_dict(cfg, env), device=device, schedule=stages,
                          checkpoint_dir=checkpoint_dir, log=log, progress=progress,
                          log_dir=checkpoint_dir.parent if checkpoint_dir is not None else None)
    alg = runner.alg
    if alg.amp_enabled:
        alg.reference_sampler = amp_reference_sampler(
            lib, cfg.env.amp_obs_steps, env.dt, cfg.env.task_specific_discrimination, device,
            plan=[canonical_name(s) for s in cfg.task.plan], weights=cfg.train.amp.skill_weights, skills=env.skills)
    assist = cfg.train.balance_assist
    if assist.torque > 0.0 or assist.damping > 0.0:
        def balance_assist(it: int) -> dict[str, float]:
            scale = assist.scale(it)
            env.world.assist.set(assist.torque * scale, assist.damping * scale)
            return {"Train/balance_assist": scale}

        runner.before_iteration = balance_assist
    alg.critic_warmup_iterations = cfg.train.critic_warmup_iterations
    alg.critic_warmup_lr = cfg.train.critic_warmup_learning_rate
    alg.reuse_frozen_features = cfg.train.reuse_frozen_features
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
    bound_coef = cfg.train.action_bound_coef
    if teachers is not None or bound_coef > 0:
        def policy_loss(obs):
            """The teachers' loss and the action-bound penalty from one pass of the actor."""
            mu = alg.actor(obs)
            terms = ([teachers.loss(mu, obs)] if teachers is not None else []) + \
                ([action_bound_loss(mu, bound_coef)] if bound_coef > 0 else [])
            total = sum((loss for loss, _ in terms), torch.zeros((), device=mu.device))
            return total, {key: value for _, logs in terms for key, value in logs.items()}

        alg.policy_loss_fn = policy_loss
        alg.teacher_only = cfg.train.teacher_only
    return env, runner


def train_worker(cfg: RunConfig) -> None:
    """A torchrun rank > 0 (`detach.train.distributed`): the same runner without run folder,
    log or progress bar, training in step with rank 0, whose weights it receives when
    training starts."""
    _env, runner = build_runner(cfg, None, cfg.device, log=None, progress=False)
    runner.learn(cfg.train.max_iterations, init_at_random_ep_len=cfg.train.init_at_random_ep_len)


def _fit(target: dict[str, torch.Tensor], source: dict[str, torch.Tensor], new: tuple[str, ...]) -> list[str]:
    """Why `source` does not fit `target` (empty if it does); keys starting with a prefix of
    `new` may be missing from the source (modules the target adds, e.g. adapters)."""
    missing = [k for k in target if k not in source and not k.startswith(new)]
    unexpected = [k for k in source if k not in target]
    shapes = [f"{k} {tuple(source[k].shape)} vs {tuple(target[k].shape)}" for k in target
              if k in source and source[k].shape != target[k].shape]
    problems = []
    for what, keys in (("missing", missing), ("unexpected", unexpected), ("of another shape", shapes)):
        if keys:
            problems.append(f"{len(keys)} {what} (e.g. {keys[0]})")
    return problems


def load_initial_weights(runner: DetachRunner, cfg: RunConfig) -> str:
    """Load `train.init_from` into the runner's actor, critic (normalisers included) and
    discriminators; ConfigError naming both models when the architectures differ. Returns a
    line for the log."""
    checkpoint, run = find_init_checkpoint(str(cfg.train.init_from))
    source_model = "?"
    if run is not None:
        try:
            source_cfg = load_run_config(RunFolder(run).config_path)
            source_model = f"{source_cfg.model_name} ({source_cfg.model.kind})"
        except ConfigError:
            source_model = f"? (unreadable {CONFIG_FILE})"
    try:
        state = read_checkpoint(Path(checkpoint), runner.device)
    except CheckpointError as exc:
        raise ConfigError(f"train.init_from: {exc}") from None
    infos = state.get("infos") if isinstance(state, dict) else None
    if run is None and isinstance(infos, dict) and "model" in infos:  # a shipped file (export --format init)
        source_model = f"{infos['model']} ({infos.get('model_kind', '?')})"
    alg = runner.alg
    parts = [("actor", alg.actor, state.get("actor_state_dict")),
             ("critic", alg.critic, state.get("critic_state_dict"))]
    if alg.amp_enabled and "discriminator_state_dict" in state:
        parts.append(("discriminator", alg.discriminators, state["discriminator_state_dict"]))
    for name, module, source in parts:
        if not isinstance(source, dict):
            raise ConfigError(f"train.init_from: {checkpoint} has no {name} weights")
        new = new_parameter_prefixes(module)
        problems = _fit(module.state_dict(), source, new)
        if problems:
            raise ConfigError(f"train.init_from: {checkpoint} holds model {source_model}, which does not fit "
                              f"this run's model {cfg.model_name} ({cfg.model.kind}): {name} " + "; ".join(problems))
        module.load_state_dict(source, strict=False)
    copied = getattr(alg.actor, "start_from_loaded", lambda: [])()  # TokenHSI's `tokenizer_from`
    restarted = ""
    if cfg.train.init_normalizers == "restart":
        restarted = f", {restart_normalizers(alg.actor, alg.critic)} observation normalisers restarted"
    elif cfg.train.init_normalizers == "merge":
        merged, zeroed = merge_normalizers(alg.actor, alg.critic)
        restarted = f", {merged} observation normalisers merged ({zeroed} weight columns on unseen inputs zeroed)"
    if cfg.train.init_action_std is not None:
        restarted += f", action std {set_action_std(alg.actor, cfg.train.init_action_std):.2f} -> " \
                     f"{cfg.train.init_action_std:g}"
    if cfg.train.init_action_mean:
        restarted += ", " + apply_action_means(alg.actor, cfg.env.character, cfg.train.init_action_mean)
    if copied:
        restarted += f", task tokenizers copied: {', '.join(copied)}"
    return f"initialised from {checkpoint} (model {source_model}, iteration {state.get('iter', '?')}{restarted})"


def set_action_std(actor: torch.nn.Module, std: float) -> float:
    """Set every action dimension's std of `actor`'s Gaussian (rsl-rl's scalar or log
    parameter) to `std`; returns the mean std it had."""
    dist = getattr(actor, "distribution", None)
    if hasattr(dist, "std_param"):
        before = float(dist.std_param.detach().mean())
        with torch.no_grad():
            dist.std_param.fill_(std)
    elif hasattr(dist, "log_std_param"):
        before = float(dist.log_std_param.detach().exp().mean())
        with torch.no_grad():
            dist.log_std_param.fill_(math.log(std))
    else:
        raise ConfigError(f"train.init_action_std: the policy's distribution ({type(dist).__name__}) has no "
                          "state-independent std to set")
    return before


def apply_action_means(actor: torch.nn.Module, character: str, means: dict[str, float]) -> str:
    """`set_action_means` by the character's action names (`train.init_action_mean`); returns
    a phrase for the log."""
    named = character_class(character).named_actions
    norms = set_action_means(actor, {named[a]: v for a, v in means.items()})
    return ", ".join(f"{a} mean {v:g} in every state (its output row's norm {n:.2f} before)"
                     for (a, v), n in zip(means.items(), norms))


def action_mean_layer(actor: torch.nn.Module) -> torch.nn.Linear:
    """The output layer of `actor`'s head (rsl-rl's `mlp`, whose last Linear writes the
    Gaussian's mean); ConfigError for a policy without one."""
    layers = [m for m in actor.mlp.modules() if isinstance(m, torch.nn.Linear)]
    if not layers or layers[-1].out_features != actor.distribution.output_dim:
        raise ConfigError(f"train.init_action_mean: the policy ({type(actor).__name__}) has no output layer "
                          "that writes the action mean")
    return layers[-1]


def set_action_means(actor: torch.nn.Module, means: dict[int, float]) -> list[float]:
    """Make each action of `means` (index -> value) start at that mean in every state: its row
    of `action_mean_layer` zeroed, its bias the value; returns the norm each row had (weights
    and bias, for the log)."""
    out = action_mean_layer(actor)
    with torch.no_grad():
        before = [float(torch.cat([out.weight[a], out.bias[a:a + 1]]).norm()) for a in means]
        for action, value in means.items():
            out.weight[action] = 0.0
            out.bias[action] = value
    return before


UNSEEN_VAR = 1e-12
"""An input whose variance in the source run's statistics is at most this never varied there."""


def merge_normalizers(*modules: torch.nn.Module) -> tuple[int, int]:
    """Keep the source's observation statistics for the inputs it saw vary, take this run's
    task's for the inputs it never saw vary, and start the weights that read those inputs at
    zero (`train.init_normalizers: merge`); returns how many normalisers changed and how many
    weight columns were zeroed.

    Why not restart them all: the policy is a function of the normalised inputs, so new
    statistics for the inputs it has learned from change what it does with them (a Carry
    policy started from Follow, an LH1 policy from Carry). Kept as they are, the inputs the
    source never varied (Follow's box, its empty height map) are divided by rsl-rl's eps
    (`restart_normalizers`).

    Until this run's first update an unseen input normalises to ~0 (its std held at 1e6), the
    value the policy saw in the source; the first update sets its mean and variance to that
    batch's, and later updates weigh it like every other input (by the kept sample count).
    The source never trained the weights that read such an input (its gradient was 0), so
    they are still their random initialisation: with the new statistics they would turn the
    new inputs into noise on every action (Follow's policy walked to Carry's box before the
    first update and away from it after). Zeroed (the model's `input_weights()`: a column is
    zeroed when its input is unseen in every frame it reads), the new inputs enter the policy
    only as fast as the gradient takes them in. Frozen normalisers and weights of a frozen
    pre-trained policy are treated as in `restart_normalizers` and left as they are.
    """
    count = zeroed = 0
    for module, name, norm, frozen in _normalizers(modules):
        unseen = _hold_unseen(norm)
        if not frozen:
            _take_unseen_from_first_update(norm, unseen)
            if name == "obs_normalizer" and hasattr(module, "input_weights"):  # the model's own input
                zeroed += zero_unseen_input_weights(module, unseen)
        count += 1
    return count, zeroed


def zero_unseen_input_weights(module: torch.nn.Module, unseen: torch.Tensor) -> int:
    """Zero the columns of `module.input_weights()` whose inputs are all in `unseen` [D] (the
    normaliser's output columns), in the parameters and in any stored copy of them (DETACH's
    θ*); returns how many parameter columns were zeroed."""
    zeroed = 0
    with torch.no_grad():
        for weight, cols in module.input_weights():
            cols = cols.to(unseen.device)
            read = cols >= 0
            idle = torch.where(read, unseen[cols.clamp(min=0)], torch.ones_like(read)).all(-1) & read.any(-1)
            weight[:, idle.to(weight.device)] = 0.0
            zeroed += int(idle.sum()) if isinstance(weight, torch.nn.Parameter) else 0
    return zeroed


def _normalizers(modules: Sequence[torch.nn.Module]
                 ) -> Iterator[tuple[torch.nn.Module, str, EmpiricalNormalization, bool]]:
    """(module, name in it, normaliser, frozen) for every observation normaliser of `modules`;
    frozen: the input normaliser of a frozen pre-trained policy (`new_parameter_prefixes()`
    non-empty: TokenHSI's adapters, CML's cooperative policy), which is never updated."""
    for module in modules:
        frozen_base = bool(new_parameter_prefixes(module))
        for name, sub in module.named_modules():
            if isinstance(sub, EmpiricalNormalization):
                yield module, name, sub, frozen_base and name == "obs_normalizer"


def _hold_unseen(norm: EmpiricalNormalization) -> torch.Tensor:
    """Make the inputs the source never saw vary normalise to ~0 (std 1e6), the value it saw
    them at; returns their mask [D]."""
    unseen = (norm._var <= UNSEEN_VAR).reshape(-1)
    norm._std[..., unseen] = 1e6
    return unseen


def _take_unseen_from_first_update(norm: EmpiricalNormalization, unseen: torch.Tensor) -> None:
    """On `norm`'s next update, set the unseen inputs' statistics to that batch's (once)."""
    def update(x: torch.Tensor) -> None:
        if not norm.training:
            return
        mean, var = x.mean(dim=0), x.var(dim=0, unbiased=False)
        del norm.update  # back to rsl-rl's update for every later call
        norm.update(x)
        with torch.no_grad():
            norm._mean[..., unseen] = mean[unseen]
            norm._var[..., unseen] = var[unseen]
            norm._std[..., unseen] = var[unseen].sqrt()

    norm.update = update


def restart_normalizers(*modules: torch.nn.Module) -> int:
    """Restart the observation statistics of `modules` on this run's task (`train.init_normalizers`
    says why); returns how many normalisers changed.

    A normaliser this run updates goes back to its initial state (mean 0, var 1, count 0), so
    the first update takes this task's statistics whole. The frozen input normaliser of a frozen
    pre-trained policy (`new_parameter_prefixes()` non-empty: TokenHSI's adapters, CML's
    cooperative policy) is never updated; there an input the source never saw vary is held at
    the value it saw (its std set to 1e6, so it normalises to ~0), as the frozen network knew it.
    """
    count = 0
    for _module, _name, norm, frozen in _normalizers(modules):
        if frozen:
            _hold_unseen(norm)
        else:
            norm._mean.zero_()
            norm._var.fill_(1.0)
            norm._std.fill_(1.0)
            norm.count.zero_()
        count += 1
    return count
