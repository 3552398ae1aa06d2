"""Networks of the study (DETACH, its ablations, TokenHSI, CML, MLP) as rsl-rl actor/critic models.

One module per model kind's network (trunk, rsl-rl model), each registering itself with
`register_model`; the kinds' config classes are in `detach.models.configs`, which imports no
torch. Importing this package imports no network either: the configuration layer reads the
config classes through it, so each name below is imported when first used. Entry points:
`factory.rsl_rl_model_cfgs` (train_cfg entries) and `factory.build_actor_critic`.
"""

from __future__ import annotations

from typing import TYPE_CHECKING

from detach.lazy_exports import lazy_exports

if TYPE_CHECKING:
    from detach.models.cml import CMLModel
    from detach.models.detach_net import DetachModel
    from detach.models.factory import DEFAULT_OBS_GROUPS, build_actor_critic, rsl_rl_model_cfgs
    from detach.models.mlp import MLPBaselineModel
    from detach.models.registry import (
        ModelEntry, model_class, model_label, model_order, paper_label, register_model, registered_models,
        unregister_model,
    )
    from detach.models.structured import StructuredModel
    from detach.models.tokenhsi import TokenHSIModel

_EXPORTS: dict[str, str] = {
    "DEFAULT_OBS_GROUPS": "factory", "build_actor_critic": "factory", "rsl_rl_model_cfgs": "factory",
    "CMLModel": "cml", "DetachModel": "detach_net", "MLPBaselineModel": "mlp", "TokenHSIModel": "tokenhsi",
    "StructuredModel": "structured", "ModelEntry": "registry", "model_class": "registry", "model_label": "registry",
    "model_order": "registry", "paper_label": "registry", "register_model": "registry",
    "registered_models": "registry", "unregister_model": "registry",
}
"""Public name -> the module of this package that defines it."""

__all__ = sorted(_EXPORTS)


__getattr__, __dir__ = lazy_exports(__name__, {name: f"{__name__}.{module}" for name, module in _EXPORTS.items()},
                                    globals())
