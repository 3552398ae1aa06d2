"""`detach-run export RUN_DIR`: a run's policy as ONNX or TorchScript, checked against torch.

`export_run` rebuilds the run's actor from config.yaml and a checkpoint, exports it through
the models' rsl-rl API (`as_onnx` / `as_jit`: `detach.models.flat_policy.FlatPolicy`) and
checks the exported file on observations of the run's own environment (and the same
observations scaled, to leave the normaliser's well-trodden range) against the eager actor:
onnxruntime for ONNX, `torch.jit.load` for TorchScript. Beside the file, `<name>.json` says how
to feed it: one input `obs` [N, D], the actor's groups concatenated in order, the history
groups time-major with the oldest frame first, raw (the input normaliser is in the graph);
one output `actions` [N, num_actions], the policy's mean, which the environment clamps to
[-1, 1] before its character maps them to controls.
"""

from __future__ import annotations

from dataclasses import dataclass
from pathlib import Path

import torch

from detach.config import ConfigError
from detach.envs.lh_env import make_env
from detach.models.flat_policy import FlatPolicy
from detach.models.structured import training_only_prefixes
from detach.runfolder.names import EXPORT_FORMATS, checkpoint_file, checkpoint_iteration, export_file
from detach.runfolder.atomic import atomic_write_json, atomic_write_text
from detach.runfolder.folder import RunFolder
from detach.runs.policy import load_policy
from detach.train.checkpoints import (
    check_model, load_module_weights, read_checkpoint, run_policy_checkpoint, write_checkpoint,
)
from detach.train.setup import prepare_assets

ONNX_OPSET = 18
TOLERANCE = 1e-4
"""Largest |exported - eager| action accepted (float32 kernels differ in summation order)."""
INIT_TOLERANCE = 0.05
"""Largest |float16 - float32| action mean accepted for `--format init` (actions live in [-1, 1]
and the policy's exploration std is ~1 on the puppet; float16 keeps ~3 significant digits)."""


@dataclass
class Exported:
    path: Path
    layout: Path
    iteration: int
    max_abs_diff: float
    """Over the check observations, between the exported file and the eager actor."""

    def __fspath__(self) -> str:
        return str(self.path)

    def __str__(self) -> str:
        return (f"{self.path} (input layout in {self.layout.name}; max |exported - torch| = "
                f"{self.max_abs_diff:.2g} over the check observations)")


def export_run(run_dir: Path, checkpoint: int | None = None, fmt: str = "onnx",
               out: Path | None = None, *, output: Path | None = None) -> Exported:
    """Export checkpoint `checkpoint` (an iteration; None: the run's policy,
    `detach.train.checkpoints.run_policy_checkpoint`) of a run as `fmt` (onnx | jit) to `out` (default
    <run>/exported/policy_<iteration>.onnx|.pt). ConfigError for a missing run, checkpoint or
    extra; RuntimeError when the file disagrees with torch."""
    out = out if out is not None else output
    if fmt not in EXPORT_FORMATS:
        raise ConfigError(f"--format: expected one of {', '.join(EXPORT_FORMATS)}, found '{fmt}'")
    run = RunFolder(Path(run_dir))
    if not run.config_path.exists():
        raise ConfigError("not a run folder (no config.yaml)", str(run_dir))
    if checkpoint is None:
        path = run_policy_checkpoint(run.path)
        if path is None:
            raise ConfigError("run has no readable checkpoint to export", str(run_dir))
    else:
        path = run.checkpoints / checkpoint_file(checkpoint)
        if not path.exists():
            have = ", ".join(str(checkpoint_iteration(p.name)) for p in reversed(run.checkpoint_files()))
            raise ConfigError(f"--checkpoint {checkpoint}: no {path.name} (the run has {have or 'none'})",
                              str(run.checkpoints))
    cfg = run.config()
    check_model(read_checkpoint(path), path, cfg.model_name, cfg.model.kind)  # before building anything
    prepare_assets(cfg.task)
    env = make_env(cfg, num_envs=4, device="cpu", eval_mode=True)
    actor, state = load_policy(cfg, env, path)
    iteration = int(state.get("iter", checkpoint_iteration(path.name) or 0))
    policy = FlatPolicy(actor)
    target = Path(out) if out is not None else run.export_dir / export_file(iteration, fmt)
    target.parent.mkdir(parents=True, exist_ok=True)
    obs = _check_observations(env, actor)
    if fmt in ("init", "policy"):
        return _export_half(state, actor, obs, policy, cfg, iteration, path, target, run, critic=fmt == "init")
    if fmt == "onnx":
        _write_onnx(actor, target)
        run_file = _onnx_runner(target)
    else:
        actor.as_jit().save(str(target))
        loaded = torch.jit.load(str(target), map_location="cpu")
        run_file = lambda x: loaded(torch.from_numpy(x)).detach().numpy()  # noqa: E731
    flat = torch.cat([obs[g] for g in policy.groups], dim=-1)
    with torch.no_grad():
        eager = actor(obs).numpy()
    diff = float(abs(run_file(flat.numpy()) - eager).max())
    if not diff <= TOLERANCE:
        raise RuntimeError(f"the exported policy differs from the eager one by {diff:.3g} (> {TOLERANCE})")
    layout = target.with_suffix(".json")
    atomic_write_json(layout, _layout(policy, cfg, iteration, path, fmt, target, diff))
    return Exported(target, layout, iteration, diff)


def _check_observations(env, actor) -> dict[str, torch.Tensor]:
    """A few steps of the run's environment under the policy, and the same observations
    scaled by 3 (inputs the normaliser maps far from 0), as one batch of named groups."""
    batches = []
    obs = env.get_observations()
    with torch.no_grad():
        for _ in range(3):
            batches.append({g: obs[g].clone() for g in actor.obs_groups})
            obs, _r, _d, _e = env.step(actor(obs))
    groups = {g: torch.cat([b[g] for b in batches]) for g in actor.obs_groups}
    scaled = {g: v * (1.0 if g == "task" else 3.0) for g, v in groups.items()}  # task stays one-hot
    return {g: torch.cat([groups[g], scaled[g]]).float() for g in actor.obs_groups}


def _write_onnx(actor, target: Path) -> None:
    try:
        import onnx  # noqa: F401  (torch's exporter needs it)
    except ImportError:
        raise ConfigError("--format onnx needs onnx (a dependency of rsl-rl-lib): pip install 'detach[export]'") \
            from None
    policy = actor.as_onnx()
    with torch.no_grad():
        torch.onnx.export(policy, policy.get_dummy_inputs(), str(target), dynamo=False,
                          export_params=True, opset_version=ONNX_OPSET, input_names=policy.input_names,
                          output_names=policy.output_names,
                          dynamic_axes={"obs": {0: "batch"}, "actions": {0: "batch"}})


def _onnx_runner(path: Path):
    try:
        import onnxruntime
    except ImportError:
        raise ConfigError("checking an ONNX export needs onnxruntime: pip install 'detach[export]'") from None
    session = onnxruntime.InferenceSession(str(path), providers=["CPUExecutionProvider"])
    return lambda x: session.run(["actions"], {"obs": x.astype("float32")})[0]


def _layout(policy: FlatPolicy, cfg, iteration: int, checkpoint: Path, fmt: str, target: Path,
            diff: float) -> dict:
    start, groups = 0, []
    for name, width in zip(policy.groups, policy.dims):
        entry = {"name": name, "start": start, "width": width}
        if name in policy.history:
            steps, dim = policy.history[name]
            entry["history"] = {"steps": steps, "frame": dim, "order": "time-major, oldest frame first"}
        groups.append(entry)
        start += width
    return {"format": fmt, "file": target.name, "model": cfg.model_name, "kind": cfg.model.kind,
            "task": cfg.task_name, "character": cfg.env.character, "iteration": iteration,
            "checkpoint": str(checkpoint), "input": {"name": "obs", "width": policy.input_size, "groups": groups,
                                                     "normalised": "inside the graph (feed raw observations)"},
            "output": {"name": "actions", "width": policy.num_actions,
                       "meaning": "the policy's mean action; the environment clamps it to [-1, 1]"},
            "check": {"max_abs_diff": diff, "tolerance": TOLERANCE}}


def _cell(run: RunFolder) -> str | None:
    try:
        return run.status().cell
    except (OSError, ValueError):
        return None


def _half(weights: dict[str, torch.Tensor]) -> dict[str, torch.Tensor]:
    """Floating weights in float16, except the input normalisers' statistics (their variances
    can leave float16's range) and anything not floating (counts, masks)."""
    return {k: v.half() if v.is_floating_point() and "normalizer" not in k else v.clone() for k, v in weights.items()}


def _export_half(state: dict, actor: torch.nn.Module, obs: dict[str, torch.Tensor], policy: FlatPolicy, cfg,
                 iteration: int, checkpoint: Path, target: Path, run: RunFolder, critic: bool) -> Exported:
    """`--format init`: the checkpoint's actor and critic (float16, normalisers float32) and its
    model names, for `train.init_from` (which reads a checkpoint file, `detach.train.setup`).
    `--format policy`: the actor alone, with the run's resolved config in the JSON beside it,
    so that `detach-run eval FILE` evaluates it without its run folder (what a study ships).
    Small enough to ship (~2 bytes per parameter): no optimiser, AMP replay or discriminator (a
    run started from it trains a fresh one); a policy also leaves out the modules only training
    reads (`training_only_prefixes`: DETACH's pre-training heads and anchors). Checked: the
    actor with the float16 weights against the float32 one on the check observations."""
    infos = {"model": cfg.model_name, "model_kind": cfg.model.kind, "task": cfg.task_name,
             "character": cfg.env.character}
    drop = () if critic else training_only_prefixes(actor)  # a policy only acts
    weights = {k: v for k, v in state["actor_state_dict"].items() if not k.startswith(drop)}
    small = {"actor_state_dict": _half(weights), "iter": iteration, "infos": infos}
    if critic:
        small["critic_state_dict"] = _half(state["critic_state_dict"])
    with torch.no_grad():
        eager = actor(obs)
        load_module_weights(actor, small["actor_state_dict"], target, "actor", may_lack=drop)
        diff = float((actor(obs) - eager).abs().max())
    if not diff <= INIT_TOLERANCE:
        raise RuntimeError(f"the float16 policy differs from the float32 one by {diff:.3g} (> {INIT_TOLERANCE})")
    write_checkpoint(target, small)
    layout = target.with_name(target.name.removesuffix(".pt") + ".json")
    info = _layout(policy, cfg, iteration, checkpoint, "init" if critic else "policy", target, diff)
    info["check"]["tolerance"] = INIT_TOLERANCE
    info["input"]["normalised"] = "by the actor's obs_normalizer, whose statistics the file holds"
    if critic:
        info["use"] = f"train.init_from={target.name} (actor and critic; float16 weights, float32 normalisers)"
    else:
        info["use"] = f"detach-run eval {target.name} --task TASK --seed S (the actor; float16 weights)"
        info["seed"], info["cell"] = cfg.seed, _cell(run)
        config = target.with_name(target.name.removesuffix(".pt") + ".yaml")
        atomic_write_text(config, run.config_path.read_text())
        info["config"] = config.name
    atomic_write_json(layout, info)
    return Exported(target, layout, iteration, diff)
