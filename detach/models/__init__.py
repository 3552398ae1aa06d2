"""Networks of the study (DETACH, its ablations, TokenHSI, CML, MLP) as rsl-rl actor/critic models.

One module per model kind (config, trunk, rsl-rl model), each registering itself with
`register_model`; they are imported here in the tables' row order. Entry points:
`factory.rsl_rl_model_cfgs` (train_cfg entries) and `factory.build_actor_critic`.
"""

from detach.models.mlp import MLPBaselineModel  # noqa: I001 (import order = registration order)
from detach.models.cml import CMLModel
from detach.models.tokenhsi import TokenHSIModel
from detach.models.detach_net import DetachModel
from detach.models.factory import DEFAULT_OBS_GROUPS, build_actor_critic, rsl_rl_model_cfgs
from detach.models.registry import (
    ModelEntry, model_class, model_label, model_order, paper_label, register_model, registered_models,
    unregister_model,
)
from detach.models.structured import StructuredModel

__all__ = [
    "DEFAULT_OBS_GROUPS",
    "CMLModel",
    "DetachModel",
    "MLPBaselineModel",
    "ModelEntry",
    "StructuredModel",
    "TokenHSIModel",
    "build_actor_critic",
    "model_class",
    "model_label",
    "model_order",
    "paper_label",
    "register_model",
    "registered_models",
    "rsl_rl_model_cfgs",
    "unregister_model",
]
