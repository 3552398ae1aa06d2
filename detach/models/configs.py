"""The config classes of the built-in model kinds, apart from their networks (no torch).

The configuration layer validates a run's `model` section into one of these without importing
any network: it imports this module by name (`detach.config.schema.BUILTIN_MODELS`), which
registers each kind's class with `register_model_kind`. Each network module
(`BUILTIN_NETWORKS`) registers its network for the kind with `register_model`. An add-on may
keep its config class and its network in one module (`examples/linear_model.py`).
"""

from __future__ import annotations

from collections.abc import Callable
from dataclasses import dataclass, field
from typing import ClassVar, Literal

from detach.config.schema import ModelCfg, kind_of, register_model_kind


@dataclass(frozen=True)
class TrunkModelCfg(ModelCfg):
    """Config of a model with a trunk the critic may share (every kind but the flat MLP)."""

    shared_trunk: bool = False
    """The critic reads the actor's trunk: its value head sees [h; privileged groups] (the
    paper's V(s) = ValueHead(h_transformer)), so one trunk is trained and run per update."""


@dataclass(frozen=True)
class MLPCfg(ModelCfg):
    """The flat MLP baseline (kind `mlp`)."""

    kind: str = "mlp"
    history_frames: int = 0
    """The newest frames of each history group the network reads (0 = all T)."""

    def invalid(self) -> tuple[str, str] | None:
        if self.history_frames < 0:
            return "history_frames", f"expected >= 0 (0 = every frame), found {self.history_frames}"
        return None


@dataclass(frozen=True)
class CMLCfg(TrunkModelCfg):
    """The CML baseline (kind `cml`)."""

    kind: str = "cml"
    gru_hidden: int = 256
    incremental: bool = False
    """The policy is a frozen meta policy (this network, weights from `train.init_from`) plus a
    trainable cooperative policy that mixes its action in per action dimension."""

    def builds_on(self) -> str | None:
        return "incremental" if self.incremental else None

    def invalid(self) -> tuple[str, str] | None:
        if self.incremental and self.shared_trunk:
            return "incremental", "the meta policy is frozen; a critic cannot share its trunk (shared_trunk)"
        return None


@dataclass(frozen=True)
class TokenHSICfg(TrunkModelCfg):
    """TokenHSI (kind `tokenhsi`); defaults are TokenHSI's published network settings."""

    kind: str = "tokenhsi"
    d_model: int = 64
    num_layers: int = 4
    num_heads: int = 2
    ff_dim: int = 512
    tokenizer_units: tuple[int, ...] = (256, 128)
    self_frames: int = 1
    """Newest frames of the `self` history the proprioception tokenizer reads (0 = all)."""
    critic_units: tuple[int, ...] = (2048, 1024, 512)
    """Hidden widths of the separate critic MLP (unused with `shared_trunk`)."""
    adapt_skills: tuple[str, ...] = ()
    """Adapter stage: these skills' task tokenizers and the head adapter train, everything else
    of the policy (tokenizers, action token, transformer, head, input normaliser) is frozen
    at the weights of the previous stage (`train.init_from`). Empty = ordinary training."""
    tokenizer_from: dict[str, str] = field(default_factory=dict)
    """With `train.init_from`: skill -> trained skill. Each named skill's task tokenizer, if
    the source run never ran that skill, starts as a copy of the other skill's
    (`TokenHSITrunk.copy_task_tokenizer`), as TokenHSI's skill adaptation starts a new task's
    tokenizer from its base task's. Without it a skill the source never ran starts at its
    random initialisation: the masking hides the trained tokenizers from it. Empty = none."""

    def builds_on(self) -> str | None:
        return "adapt_skills" if self.adapt_skills else None

    def invalid(self) -> tuple[str, str] | None:
        """Rules among the fields (those on skill names: `invalid_skills`)."""
        if self.self_frames < 0:
            return "self_frames", f"expected >= 0 (0 = every frame), found {self.self_frames}"
        if self.adapt_skills and self.shared_trunk:
            return "adapt_skills", "the adapter stage freezes the transformer; use it without shared_trunk"
        return None

    def invalid_skills(self, canonical_name: Callable[[str], str]) -> tuple[str, str] | None:
        """Rules on the skill names, through the skills registry's `canonical_name`: checked when
        a run's config is completed (the registry imports the skills, hence torch)."""
        try:
            names = [canonical_name(s) for s in self.adapt_skills]
        except ValueError as exc:
            return "adapt_skills", str(exc)
        if len(set(names)) != len(names):
            return "adapt_skills", f"a skill is listed twice: {list(self.adapt_skills)}"
        try:
            pairs = [(canonical_name(a), canonical_name(b)) for a, b in self.tokenizer_from.items()]
        except ValueError as exc:
            return "tokenizer_from", str(exc)
        if any(a == b for a, b in pairs):
            return "tokenizer_from", f"a skill copies its own tokenizer: {dict(self.tokenizer_from)}"
        return None


@dataclass(frozen=True)
class EnvEncoderCfg:
    kernel_sizes: tuple[int, ...] = (1, 3, 5)
    channels: int = 64
    attn_heads: int = 4
    decoder_hidden: int = 256
    """Hidden width of Decoder_env (per-frame MLP z_env[t] -> env frame)."""


@dataclass(frozen=True)
class SelfEncoderCfg:
    hidden: int = 64
    layers: int = 1
    decoder_hidden: int = 256
    """Hidden width of Decoder_self (per-frame MLP z_self[t] -> self frame)."""
    predictor_hidden: int = 128
    """Hidden width of the temporal predictor f_pred."""


@dataclass(frozen=True)
class FusionCfg:
    cross_attn_heads: int = 8
    gate_hidden: tuple[int, ...] = (128, 64)
    num_experts: int = 4
    expert_hidden: tuple[int, ...] = (128, 64)


@dataclass(frozen=True)
class RegularizerCfg:
    """Weights of DETACH's auxiliary losses (the paper gives no values; see detach.yaml)."""

    lambda_quality: float = 0.1
    lambda_disentangle: float = 0.01
    lambda_r1: float = 0.01
    lambda_r2: float = 0.01
    lambda_r3: float = 0.001
    lambda_temporal: float = 0.001
    lambda_semantic: float = 0.01
    lambda_decouple: float = 0.01
    """Weight of R_decouple = ||Corr(z_env, z_self)||_F^2 in the joint stage."""
    semantic_env_weight: float = 1.0
    """alpha of R_semantic (env reconstruction term)."""
    semantic_self_weight: float = 1.0
    """beta of R_semantic (self reconstruction term)."""
    r3_mode: Literal["distance", "cosine"] = "distance"
    """R3 as printed in the paper (sum of squared distances between fusion outputs, which
    pulls them together) or `cosine` (mean squared cosine similarity, which pushes them apart,
    the stated intent "fusion diversity")."""


@dataclass(frozen=True)
class DetachCfg(TrunkModelCfg):
    """DETACH and its ablations A1/A2 (kind `detach`)."""

    kind: str = "detach"
    d_model: int = 64
    num_layers: int = 4
    num_heads: int = 8
    ff_dim: int = 256
    use_env_encoder: bool = True
    """False = ablation A1 (env frames through a linear projection)."""
    use_self_encoder: bool = True
    """False = ablation A2 (self frames through a linear projection)."""
    env_encoder: EnvEncoderCfg = EnvEncoderCfg()
    self_encoder: SelfEncoderCfg = SelfEncoderCfg()
    fusion: FusionCfg = FusionCfg()
    regularizers: RegularizerCfg = RegularizerCfg()

    staged: ClassVar[bool] = True


BUILTIN_NETWORKS: dict[type[ModelCfg], str] = {
    MLPCfg: "detach.models.mlp",
    CMLCfg: "detach.models.cml",
    TokenHSICfg: "detach.models.tokenhsi",
    DetachCfg: "detach.models.detach_net",
}
"""Each built-in kind's config class and the module of its network, in the tables' row order
(`detach.models.registry.registered_models`)."""

for _config_class in BUILTIN_NETWORKS:
    register_model_kind(kind_of(_config_class), _config_class)
