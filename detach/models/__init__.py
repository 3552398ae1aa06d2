"""Networks of the study (DETACH, its ablations, TokenHSI, CML, MLP) as rsl-rl actor/critic models.

Entry points: `factory.rsl_rl_model_cfgs` (train_cfg entries) and `factory.build_actor_critic`.
"""

from detach.models.factory import DEFAULT_OBS_GROUPS, MODEL_CLASSES, build_actor_critic, rsl_rl_model_cfgs
from detach.models.rsl_rl_models import CMLModel, DetachModel, MLPBaselineModel, StructuredModel, TokenHSIModel

__all__ = [
    "DEFAULT_OBS_GROUPS",
    "MODEL_CLASSES",
    "CMLModel",
    "DetachModel",
    "MLPBaselineModel",
    "StructuredModel",
    "TokenHSIModel",
    "build_actor_critic",
    "rsl_rl_model_cfgs",
]
