"""The strict, Hydra-free configuration loader (re-exported by `detach.config`).

A run's configuration is one task YAML (configs/tasks/) merged with one model YAML
(configs/models/), each possibly `extends:`-ing others (relative paths, chained, deep merge,
lists replace), then command-line overrides `a.b.c=value` (`+a.b=value` adds a key that does
not exist yet). The result is validated into `RunConfig`; `dump` writes it back as a
self-contained YAML that `load_run_config` reads to an identical object.
"""

from __future__ import annotations

import dataclasses
import re
import typing
from pathlib import Path
from typing import Any, Sequence

import yaml

from detach.config.schema import (
    EnvCfg, EvalCfg, ModelCfg, RewardsCfg, RunConfig, SimCfg, TaskCfg, TrainCfg,
)
from detach.config.ranges import check_ranges
from detach.config.validate import Builder, describe, suggest, to_plain
from detach.config.yaml_source import (
    ConfigError, ConfigOrigin, KeyPath, Provenance, format_path, load_yaml, parse_scalar,
)

TASK_SECTIONS: dict[str, Any] = {"sim": SimCfg, "env": EnvCfg, "rewards": RewardsCfg,
                                 "eval": EvalCfg}
MODEL_SECTIONS: dict[str, Any] = {"model": ModelCfg, "train": TrainCfg}
TASK_KEYS = tuple(f.name for f in dataclasses.fields(TaskCfg))
RUN_KEYS = ("task_name", "model_name", "seed", "device")
TARGET_SOURCE = re.compile(r"^(traj|tarpos|scene)_(\d+|rand)$")


# ---------------------------------------------------------------------------- extends + merge
def load_merged(file: Path, _chain: tuple[Path, ...] = ()) -> tuple[dict[str, Any], Provenance]:
    """Load `file`, following its `extends:` chain; the file's own keys win over its base."""
    file = Path(file)
    real = file.resolve()
    if real in _chain:
        cycle = " -> ".join(str(p) for p in (*_chain, real))
        raise ConfigError(f"cyclic extends: {cycle}", str(file))
    data, prov = load_yaml(file)
    if not isinstance(data, dict):
        raise ConfigError(f"expected a mapping of config keys at the top level, found "
                          f"{describe(data)}", str(file), 1)
    base_name = data.pop("extends", None)
    if base_name is None:
        return data, prov
    if not isinstance(base_name, str):
        line = prov[("extends",)][1]
        raise ConfigError(f"expected a relative file name, found {describe(base_name)}",
                          str(file), line, ("extends",))
    base_file = file.parent / base_name
    if not base_file.exists():
        line = prov[("extends",)][1]
        raise ConfigError(f"extends a file that does not exist: {base_file}", str(file), line,
                          ("extends",))
    base, base_prov = load_merged(base_file, (*_chain, real))
    return deep_merge(base, data, base_prov, prov), {**base_prov, **_without(prov, ("extends",))}


def _without(prov: Provenance, prefix: KeyPath) -> Provenance:
    return {k: v for k, v in prov.items() if k[:len(prefix)] != prefix}


def deep_merge(base: dict[str, Any], over: dict[str, Any], base_prov: Provenance,
               over_prov: Provenance, path: KeyPath = ()) -> dict[str, Any]:
    """Mappings merge key by key; anything else (lists included) is replaced.

    Provenance of replaced subtrees is dropped from `base_prov` so errors point at the file
    that really set a value.
    """
    out = dict(base)
    for key, value in over.items():
        if isinstance(value, dict) and isinstance(base.get(key), dict):
            out[key] = deep_merge(base[key], value, base_prov, over_prov, path + (key,))
        else:
            for stale in [k for k in base_prov if k[:len(path) + 1] == path + (key,)]:
                del base_prov[stale]
            out[key] = value
    return out


# ---------------------------------------------------------------------------- overrides
def _parse_key(text: str) -> KeyPath:
    """'scene[2].pos3d' or 'scene.2.pos3d' -> ('scene', 2, 'pos3d')."""
    parts: list[str | int] = []
    for token in re.split(r"\.(?![^\[]*\])", text):
        match = re.fullmatch(r"([^\[\]]*)((?:\[\d+\])*)", token)
        if not match or (not match.group(1) and not match.group(2)):
            raise ConfigError(f"bad override key '{text}'")
        if match.group(1):
            parts.append(int(match.group(1)) if match.group(1).isdigit() else match.group(1))
        parts.extend(int(i) for i in re.findall(r"\[(\d+)\]", match.group(2)))
    return tuple(parts)


def _schema_children(tp: Any, node: Any = None) -> dict[str, Any] | None:
    """Field name -> type for a dataclass type (or Optional of one), else None. A family of
    configs (`kind_class`) resolves to the class of the node's `kind`."""
    for candidate in (tp, *typing.get_args(tp)):
        if dataclasses.is_dataclass(candidate):
            if hasattr(candidate, "kind_class") and isinstance(node, dict) and isinstance(node.get("kind"), str):
                try:
                    candidate = candidate.kind_class(node["kind"])
                except ValueError:
                    pass
            hints = typing.get_type_hints(candidate)
            return {f.name: hints[f.name] for f in dataclasses.fields(candidate)}
    return None


def _top_schema() -> dict[str, Any]:
    hints = typing.get_type_hints(TaskCfg)
    return {**hints, **TASK_SECTIONS, **MODEL_SECTIONS,
            **{k: typing.get_type_hints(RunConfig)[k] for k in RUN_KEYS}}


def apply_overrides(data: dict[str, Any], overrides: Sequence[str], prov: Provenance) -> None:
    """Apply `key.path=value` overrides in place; a key unknown to both data and schema fails."""
    for text in overrides:
        origin = ("<command line>", None)
        if "=" not in text:
            raise ConfigError(f"bad override '{text}': expected key.path=value")
        key_text, value_text = text.split("=", 1)
        add = key_text.startswith("+")
        path = _parse_key(key_text.lstrip("+"))
        value = parse_scalar(value_text)
        node: Any = data
        node_tp: Any = None  # schema type of `node`; None at the top level or when free-form
        for depth, part in enumerate(path):
            last = depth == len(path) - 1
            here = path[:depth + 1]
            if isinstance(node, list):
                if not isinstance(part, int) or part >= len(node):
                    raise ConfigError(f"override '{text}': no item {part} (the list has "
                                      f"{len(node)} items)", *origin, here)
                child_tp = _list_item_type(node_tp) if node_tp is not None else None
            elif isinstance(node, dict):
                children = _top_schema() if depth == 0 else _schema_children(node_tp, node)
                known = part in node or (children is not None and part in children)
                if not known and not add:
                    valid = [str(k) for k in node] + list(children or {})
                    raise ConfigError(f"override of unknown key{suggest(str(part), valid)} "
                                      f"(use +{format_path(path)}=... to add a new key)",
                                      *origin, here)
                child_tp = children.get(part) if children else None
            else:
                raise ConfigError(f"override '{text}': {format_path(path[:depth])} is a "
                                  f"value, not a mapping", *origin, here)
            if last:
                node[part] = value
                for stale in [k for k in prov if k[:len(here)] == here]:
                    del prov[stale]
                prov[here] = ("<command line>", 0)
            else:
                if isinstance(node, dict) and node.get(part) is None:
                    node[part] = {}
                node, node_tp = node[part], child_tp


def _list_item_type(tp: Any) -> Any:
    args = [a for a in typing.get_args(tp) if a is not Ellipsis]
    return args[0] if args else None


# ---------------------------------------------------------------------------- validation
def _build_run(data: dict[str, Any], prov: Provenance, file: str,
               run_keys: dict[str, Any]) -> RunConfig:
    builder = Builder(prov, file)
    allowed = (*TASK_KEYS, *TASK_SECTIONS, *MODEL_SECTIONS, *RUN_KEYS)
    for key in data:
        if key not in allowed:
            raise builder.error((key,), f"unknown key{suggest(key, allowed)}; valid top-level "
                                        f"keys: {', '.join(allowed)}")
    task_data = {k: v for k, v in data.items() if k in TASK_KEYS}
    task_data.setdefault("name", run_keys["task_name"])
    task = builder.build(TaskCfg, task_data, ())
    check_task(task, builder)
    sections = {name: builder.build(cls, data.get(name, {}), (name,))
                for name, cls in {**TASK_SECTIONS, **MODEL_SECTIONS}.items()}
    check_model(sections["model"], builder)
    hints = typing.get_type_hints(RunConfig)
    runs = {k: builder.build(hints[k], data.get(k, run_keys[k]), (k,)) for k in RUN_KEYS}
    cfg = RunConfig(task=task, **runs, **sections, origin=ConfigOrigin(file, prov))
    check_ranges(cfg, cfg.origin)
    return cfg


def check_model(model: ModelCfg, builder: Builder) -> None:
    """A model kind's own cross-field rules (`invalid()` of its config class)."""
    invalid = getattr(model, "invalid", None)
    problem = invalid() if invalid is not None else None
    if problem is not None:
        raise builder.error(("model", problem[0]), problem[1])


def check_task(task: TaskCfg, builder: Builder) -> None:
    """Cross-field rules of the plan vocabulary that hold for every skill (each skill checks
    its own entries later: `detach.skills.plan.compile_plan`)."""
    n = len(task.plan)
    for key in ("target_object", "sample_target_from"):
        if len(getattr(task, key)) != n:
            raise builder.error((key,), f"expected {n} entries (one per plan step: "
                                        f"{list(task.plan)}), found {len(getattr(task, key))}")
    if n == 0:
        raise builder.error(("plan",), "expected at least one skill, found an empty plan")
    for i, (skill, obj, source) in enumerate(zip(task.plan, task.target_object,
                                                  task.sample_target_from)):
        match = TARGET_SOURCE.match(source)
        if not match:
            raise builder.error(("sample_target_from", i), "expected traj_K, tarpos_K or "
                                f"scene_K, found {source!r}")
        kind, index = match.group(1), match.group(2)
        if index == "rand":
            if kind != "traj":
                raise builder.error(("sample_target_from", i),
                                    f"only traj_rand may be random, found {source!r}")
        else:
            k = int(index)
            size = {"traj": len(task.trajectories), "tarpos": len(task.target_positions),
                    "scene": len(task.scene)}[kind]
            exists = k in task.trajectories if kind == "traj" else k < size
            if not exists:
                what = {"traj": "trajectories", "tarpos": "target_positions",
                        "scene": "scene"}[kind]
                have = sorted(task.trajectories) if kind == "traj" else f"{size} entries"
                raise builder.error(("sample_target_from", i),
                                    f"{source!r} names a missing {what} entry (have {have})")
    for key, points in task.trajectories.items():
        if len(points) < 2:
            raise builder.error(("trajectories", key), f"expected at least 2 waypoints, "
                                                      f"found {len(points)}")


# ---------------------------------------------------------------------------- public API
def task_name_of(task_path: Path) -> str:
    return Path(task_path).stem


def builtin_configs() -> Path:
    """The configs/ shipped with detach: `detach/configs/` inside an installed wheel (package
    data), the checkout's `configs/` in a source tree or an editable install."""
    here = Path(__file__).resolve().parent.parent  # detach/
    packaged = here / "configs"
    return packaged if packaged.is_dir() else here.parent / "configs"


def find_config_file(kind: str, name: str, task_path: Path | None = None) -> Path:
    """A YAML of configs/<kind>/ (tasks, models, presets, sweeps) given as a file path or a
    name looked up beside the task's folder, then under the working directory's configs/, then
    in the configs shipped with detach (`builtin_configs`)."""
    as_path = Path(name)
    if as_path.suffix in (".yaml", ".yml") or "/" in name or as_path.is_file():
        return as_path
    roots = []
    if task_path is not None:
        roots.append(Path(task_path).resolve().parent.parent / kind)
    roots.append(Path.cwd() / "configs" / kind)
    roots.append(builtin_configs() / kind)
    for root in roots:
        candidate = root / f"{name}.yaml"
        if candidate.exists():
            return candidate
    names = sorted({p.stem for r in roots if r.is_dir() for p in r.glob("*.yaml")})
    what = kind[:-1]
    raise ConfigError(f"unknown {what} '{name}'{suggest(name, names)}; available: "
                      f"{', '.join(names) or 'none found'}")


def find_task_file(task: str | Path) -> Path:
    """A task given as a path (`configs/tasks/lh1.yaml`) or a name (`lh1`); ConfigError naming
    the available tasks when neither exists."""
    path = find_config_file("tasks", str(task))
    if not path.is_file():
        raise ConfigError("task file not found", str(task))
    return path


def find_model_file(model: str, task_path: Path | None = None) -> Path:
    """`--model` accepts a file path or a name looked up in configs/models/."""
    return find_config_file("models", model, task_path)


def resolve(task_path: str | Path, model_name: str = "mlp", overrides: Sequence[str] = (),
            seed: int = 0, device: str = "cpu", presets: Sequence[str] = ()) -> RunConfig:
    """Task YAML + model YAML + presets (in order) + overrides -> validated RunConfig.

    A preset (configs/presets/NAME.yaml, or a path) holds sections of either kind (sim, env,
    rewards, eval, model, train) and is merged over the task and model, e.g. the paper's scale
    or TokenHSI's PPO settings; command-line overrides still win."""
    task_path = Path(task_path)
    data, prov = load_merged(task_path)
    for key in list(data):
        if key in MODEL_SECTIONS:
            raise ConfigError(f"'{key}' belongs in a model config (configs/models/), not in a "
                              f"task", str(task_path), prov.get((key,), ("", None))[1], (key,))
    model_file = find_model_file(model_name, task_path)
    model_data, model_prov = load_merged(model_file)
    for key in model_data:
        if key not in MODEL_SECTIONS:
            raise ConfigError(f"unknown key{suggest(key, MODEL_SECTIONS)}; a model config "
                              f"holds only: {', '.join(MODEL_SECTIONS)}", str(model_file),
                              model_prov.get((key,), ("", None))[1], (key,))
    data.update(model_data)
    prov.update(model_prov)
    for preset in presets:
        preset_file = find_config_file("presets", preset, task_path)
        preset_data, preset_prov = load_merged(preset_file)
        for key in preset_data:
            if key not in (*TASK_SECTIONS, *MODEL_SECTIONS):
                raise ConfigError(f"unknown key{suggest(key, (*TASK_SECTIONS, *MODEL_SECTIONS))}; a preset "
                                  f"holds only: {', '.join((*TASK_SECTIONS, *MODEL_SECTIONS))}", str(preset_file),
                                  preset_prov.get((key,), ("", None))[1], (key,))
        data = deep_merge(data, preset_data, prov, preset_prov)
        prov.update(preset_prov)
    apply_overrides(data, overrides, prov)
    run_keys = {"task_name": task_name_of(task_path), "model_name": model_file.stem,
                "seed": seed, "device": device}
    return _build_run(data, prov, str(task_path), run_keys)


LEGACY_KEYS: dict[KeyPath, str] = {
    ("rewards", "decoupling_mask_strength"): "never read",
}
"""Keys that resolved configs of older versions carry and this version dropped (with why)."""
FLAT_MODEL_FIELDS = frozenset((
    "d_model", "num_layers", "num_heads", "ff_dim", "adapter_units", "activation", "use_env_encoder",
    "use_self_encoder", "env_encoder", "self_encoder", "fusion", "regularizers", "tokenizer_units",
    "gru_hidden", "critic_objectives", "init_noise_std", "history_frames", "shared_trunk", "obs_normalization"))
"""Fields of the single model class of earlier versions; each kind now declares its own."""


def _drop_legacy(data: dict[str, Any]) -> None:
    """Let config.yaml files of earlier runs load: drop keys this version removed, and fields
    of the old single model class that the run's model kind does not declare."""
    for path in LEGACY_KEYS:
        node = data
        for key in path[:-1]:
            node = node.get(key) if isinstance(node, dict) else None
        if isinstance(node, dict):
            node.pop(path[-1], None)
    model = data.get("model")
    if isinstance(model, dict) and isinstance(model.get("kind"), str):
        try:
            cls = ModelCfg.kind_class(model["kind"])
        except ValueError:
            return
        known = {f.name for f in dataclasses.fields(cls)}
        for key in [k for k in model if k not in known and k in FLAT_MODEL_FIELDS]:
            del model[key]


def load_task(task_path: str | Path) -> TaskCfg:
    """Only the task part of a task YAML (what the asset builder needs)."""
    task_path = Path(task_path)
    data, prov = load_merged(task_path)
    builder = Builder(prov, str(task_path))
    allowed = (*TASK_KEYS, *TASK_SECTIONS)
    for key in data:
        if key not in allowed:
            raise builder.error((key,), f"unknown key{suggest(key, allowed)}")
    task_data = {k: v for k, v in data.items() if k in TASK_KEYS}
    task_data.setdefault("name", task_name_of(task_path))
    task = builder.build(TaskCfg, task_data, ())
    check_task(task, builder)
    return task


def to_dict(cfg: RunConfig) -> dict[str, Any]:
    """RunConfig -> plain, self-contained YAML data (task keys at the top level)."""
    plain = to_plain(cfg)
    task = plain.pop("task")
    return {**{k: plain.pop(k) for k in RUN_KEYS}, **task, **plain}


def dump(cfg: RunConfig) -> str:
    """YAML text of a resolved config; `load_run_config` reads it back identically."""
    header = "# Fully resolved run configuration written by detach; reload with load_run_config.\n"
    return header + yaml.safe_dump(to_dict(cfg), sort_keys=False, default_flow_style=None,
                                   width=100)


def load_run_config(path: str | Path, overrides: Sequence[str] = ()) -> RunConfig:
    """Read a run folder's config.yaml (or any self-contained dump)."""
    path = Path(path)
    data, prov = load_yaml(path)
    if not isinstance(data, dict):
        raise ConfigError(f"expected a mapping, found {describe(data)}", str(path), 1)
    if "extends" in data:
        raise ConfigError("a resolved run config cannot use extends", str(path),
                          prov[("extends",)][1], ("extends",))
    _drop_legacy(data)
    apply_overrides(data, overrides, prov)
    missing = [k for k in RUN_KEYS if k not in data]
    if missing:
        raise ConfigError(f"missing keys of a resolved run config: {', '.join(missing)}",
                          str(path), 1)
    return _build_run(data, prov, str(path), {k: data[k] for k in RUN_KEYS})
