"""The model kinds: `register_model` is the one way a network joins the study.

A model kind is a config class (a `ModelCfg` subclass, `kind` its default) and a network: a
`StructuredModel` subclass whose module ends with `register_model(TheModel, labels={...})`. The
built-in kinds' config classes live apart from their networks in `detach.models.configs` (no
torch), which the configuration layer imports by name; their networks' modules
(`configs.BUILTIN_NETWORKS`) are imported the first time this registry is asked for a network or
a label. A kind outside the package may keep both in one module, which registers when
imported: the configuration loader imports it for `kind: package.module:ConfigClass` or for an
entry point of the `detach.model_kinds` group of an installed add-on package
(`detach.config.schema`).

The registry also holds the names the tables print: `labels` maps each model YAML of the kind
(configs/models/<name>.yaml, the `model` of a run and of its eval.json) to its row label, and
`paper_labels` those the paper's own rows use where they differ. Tables list the models in
registration order: the built-ins in the order of `BUILTIN_NETWORKS`, then add-ons.
"""

from __future__ import annotations

import importlib
from collections.abc import Mapping
from dataclasses import dataclass, field

from detach.config.schema import ModelCfg, kind_of, register_model_kind
from detach.models.configs import BUILTIN_NETWORKS
from detach.models.structured import StructuredModel


@dataclass(frozen=True)
class ModelEntry:
    """One registered model kind: its network and the labels of its model YAMLs."""

    network: type[StructuredModel]
    labels: Mapping[str, str] = field(default_factory=dict)
    """Row label of each model YAML of this kind (e.g. ablation_a1 -> "A1 (w/o env encoder)")."""
    paper_labels: Mapping[str, str] = field(default_factory=dict)
    """The paper's name of a model YAML where it differs from `labels` (ablation_a1 -> "A1")."""

    @property
    def config_class(self) -> type[ModelCfg]:
        return self.network.config_class

    @property
    def kind(self) -> str:
        return kind_of(self.network.config_class)


_MODELS: dict[str, ModelEntry] = {}
_BUILTIN_ORDER = {kind_of(config_class): i for i, config_class in enumerate(BUILTIN_NETWORKS)}
_builtins_loaded = False


def load_builtin_networks() -> None:
    """Import the built-in networks' modules (each registers its kind), once per process."""
    global _builtins_loaded
    if _builtins_loaded:
        return
    _builtins_loaded = True  # first: each module registers through register_model, which calls this
    try:
        for module in BUILTIN_NETWORKS.values():
            importlib.import_module(module)
    except BaseException:
        _builtins_loaded = False
        raise


def register_model(network: type[StructuredModel], labels: Mapping[str, str] | None = None,
                   paper_labels: Mapping[str, str] | None = None) -> type[StructuredModel]:
    """Register `network` as the model of its `config_class`'s kind; returns it.

    Registering the same network again (a module imported twice) changes nothing; another
    network for a registered kind is a ValueError naming both."""
    config_class = getattr(network, "config_class", None)
    if not (isinstance(network, type) and issubclass(network, StructuredModel)
            and isinstance(config_class, type) and issubclass(config_class, ModelCfg)):
        raise ValueError(f"register_model: {network!r} is not a StructuredModel subclass with a "
                         f"ModelCfg subclass as its config_class")
    load_builtin_networks()  # an add-on cannot take a built-in kind before it is registered
    kind = kind_of(config_class)
    old = _MODELS.get(kind)
    if old is not None and old.network is not network:
        raise ValueError(f"model kind '{kind}' is already registered to {_path(old.network)}; "
                         f"{_path(network)} needs another kind")
    register_model_kind(kind, config_class)
    _MODELS[kind] = ModelEntry(network, dict(labels or {}), dict(paper_labels or {}))
    return network


def unregister_model(kind: str) -> None:
    """Remove a model kind (tests that register one of their own)."""
    del _MODELS[kind]
    register_model_kind(kind, None)


def registered_models() -> tuple[ModelEntry, ...]:
    """Every registered model kind: the built-ins in the order of `BUILTIN_NETWORKS` (however
    their modules were first imported), then the others in registration order."""
    load_builtin_networks()
    return tuple(sorted(_MODELS.values(), key=lambda e: _BUILTIN_ORDER.get(e.kind, len(_BUILTIN_ORDER))))


def model_class(model_cfg: ModelCfg) -> type[StructuredModel]:
    """The network of a model config: the registered kind whose config class it is."""
    for entry in registered_models():
        if type(model_cfg) is entry.config_class:
            return entry.network
    raise ValueError(f"no network for model kind '{model_cfg.kind}' ({type(model_cfg).__name__}); its "
                     f"module registers one with detach.models.register_model")


def model_label(name: str) -> str:
    """The row label of a model YAML's name (the name itself for a model no kind labels)."""
    for entry in registered_models():
        if name in entry.labels:
            return entry.labels[name]
    return name


def paper_label(name: str) -> str:
    """The name the paper gives a model YAML's method (its row label unless it differs)."""
    for entry in registered_models():
        if name in entry.paper_labels:
            return entry.paper_labels[name]
    return model_label(name)


def model_order() -> tuple[str, ...]:
    """The labelled model names in registration order (the row order of the tables)."""
    return tuple(name for entry in registered_models() for name in entry.labels)


def _path(cls: type) -> str:
    return f"{cls.__module__}:{cls.__qualname__}"
