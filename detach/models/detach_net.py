"""DETACH (kind `detach`, with its ablations A1/A2; config `configs.DetachCfg`): trunk (dual
encoders -> projections -> adaptive fusion -> shared transformer φ) and rsl-rl model.

Tokens of φ (our choice; the paper only says φ(f_fused)): one fused token per self-history step
(T_self tokens, f_fused[t] = fusion of f_self[t] with the env sequence) + one task token
(linear embedding of the skill one-hot) + one token per extra flat group (the privileged
`critic` group in the critic), plus learned position embeddings. The output tokens are
flattened into the latent [N, n_tokens * d_model] that the adapter MLP (policy or value head,
`DetachModel`) consumes; flattening keeps which step each token came from.

Ablations are switches: `use_env_encoder = False` (A1) drops Φ_env and Decoder_env and feeds
env frames through P_env = Linear(d_env, d_model) directly; `use_self_encoder = False` (A2)
likewise drops Φ_self, Decoder_self and f_pred. For an ablated stream z := f (the projection
output), so the decoupling terms still act on what represents that stream.
"""

from __future__ import annotations

from collections.abc import Iterator
from dataclasses import dataclass
from itertools import chain

import torch
import torch.nn as nn
from tensordict import TensorDict

from detach.models import losses
from detach.models.attention import TransformerEncoder
from detach.models.configs import DetachCfg, RegularizerCfg
from detach.models.encoders import EnvEncoder, FrameDecoder, SelfEncoder, TemporalPredictor
from detach.models.fusion import AdaptiveFusion, FusionOutput
from detach.models.layout import ObsLayout, no_columns
from detach.models.losses import combine_aux_losses
from detach.models.registry import register_model
from detach.models.structured import StructuredModel


class ParamAnchor(nn.Module):
    """θ* of one encoder for R1/R2: buffer copies of its parameters.

    Buffers (not parameters) so they are saved in checkpoints (stage 3 can resume) but never
    optimised. `valid` is False until `store` is called.
    """

    def __init__(self, module: nn.Module) -> None:
        super().__init__()
        self._keys = [n.replace(".", "__") for n, _ in module.named_parameters()]
        for key, (_, p) in zip(self._keys, module.named_parameters()):
            self.register_buffer(key, p.detach().clone())
        self.register_buffer("valid", torch.tensor(False))

    def anchors(self) -> list[torch.Tensor]:
        return [getattr(self, k) for k in self._keys]

    def copy_of(self, name: str) -> torch.Tensor:
        """θ* of the encoder's parameter `name` (as `named_parameters` names it)."""
        return getattr(self, name.replace(".", "__"))

    @torch.no_grad()
    def store(self, module: nn.Module) -> None:
        for a, p in zip(self.anchors(), module.parameters(), strict=True):
            a.copy_(p)
        self.valid.fill_(True)


@dataclass
class DetachFeatures:
    """Intermediates of one forward pass: z_* [N, T_*, z_dim], f_* [N, T_*, d_model]."""

    z_env: torch.Tensor
    z_self: torch.Tensor
    f_env: torch.Tensor
    f_self: torch.Tensor
    fusion: FusionOutput


PRETRAIN_HEADS = ("env_decoder", "self_decoder", "predictor")
"""DetachTrunk's modules trained only by the auxiliary losses (Decoder_env, Decoder_self, f_pred)."""
ANCHORS = ("env_anchor", "self_anchor")
"""DetachTrunk's copies θ*_env, θ*_self of the encoders, read only by R1/R2."""


class DetachTrunk(nn.Module):
    """Named groups {self [N,T,d], env [N,T,d], task [N,S], extras [N,D]} -> latent [N, out_dim]."""

    def __init__(self, layout: ObsLayout, cfg: DetachCfg) -> None:
        super().__init__()
        layout.require("self", "env", "task")
        self.layout = layout
        t_self, d_self = layout.history_shape("self")
        _, d_env = layout.history_shape("env")
        d, act = cfg.d_model, cfg.activation

        self.env_encoder: EnvEncoder | None = None
        self.env_decoder: FrameDecoder | None = None
        if cfg.use_env_encoder:
            self.env_encoder = EnvEncoder(d_env, cfg.env_encoder, act)
            self.env_decoder = FrameDecoder(self.env_encoder.out_dim, d_env, cfg.env_encoder.decoder_hidden, act)
        self.proj_env = nn.Linear(self.env_encoder.out_dim if self.env_encoder else d_env, d)

        self.self_encoder: SelfEncoder | None = None
        self.self_decoder: FrameDecoder | None = None
        self.predictor: TemporalPredictor | None = None
        if cfg.use_self_encoder:
            sc = cfg.self_encoder
            self.self_encoder = SelfEncoder(d_self, sc)
            self.self_decoder = FrameDecoder(self.self_encoder.out_dim, d_self, sc.decoder_hidden, act)
            self.predictor = TemporalPredictor(self.self_encoder.out_dim, sc.predictor_hidden, act)
        self.proj_self = nn.Linear(self.self_encoder.out_dim if self.self_encoder else d_self, d)

        self.fusion = AdaptiveFusion(d, cfg.fusion, act)
        self.task_token = nn.Linear(layout.dim("task"), d)
        self.extra_tokens = nn.ModuleDict({g: nn.Linear(layout.dim(g), d) for g in layout.extra_groups})
        n_tokens = t_self + 1 + len(layout.extra_groups)
        self.pos = nn.Parameter(0.02 * torch.randn(1, n_tokens, d))
        self.transformer = TransformerEncoder(d, cfg.num_heads, cfg.ff_dim, cfg.num_layers)
        self.out_dim = n_tokens * d

        self.env_anchor = ParamAnchor(self.env_encoder) if self.env_encoder else None
        self.self_anchor = ParamAnchor(self.self_encoder) if self.self_encoder else None

    # ----- input layers (`train.init_normalizers: merge`) -----
    def input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """(weight [out, in], its input columns [in, F] in the layout) of every layer that
        reads the normalised groups directly, then the encoders' stored copies of theirs."""
        lay = self.layout
        env = self.env_encoder.embed[0].weight if self.env_encoder else self.proj_env.weight
        if self.self_encoder:
            gru = self.self_encoder.gru
            own = [getattr(gru, n) for n in ("weight_ih_l0", "weight_ih_l0_reverse") if hasattr(gru, n)]
        else:
            own = [self.proj_self.weight]
        out = [(env, lay.columns("env")), (self.task_token.weight, lay.columns("task"))]
        out += [(w, lay.columns("self")) for w in own]
        out += [(self.extra_tokens[g].weight, lay.columns(g)) for g in lay.extra_groups]
        return out + self._anchored_input_weights()

    def _anchored_input_weights(self) -> list[tuple[torch.Tensor, torch.Tensor]]:
        """θ* (R1/R2's copies) of the encoders' input weights, with the same columns: what
        changes those weights (`train.init_normalizers: merge` zeroes the columns of inputs
        the source never saw vary) changes their copies too, or R1/R2 would pull the weights
        back to what was changed (R1 was 20 from the first Carry iteration, pulling the
        zeroed random weights on Follow's unseen box and height-map inputs back)."""
        out = []
        if self.env_encoder:
            out.append((self.env_anchor.copy_of("embed.0.weight"), self.layout.columns("env")))
        if self.self_encoder:
            names = [n for n, _ in self.self_encoder.named_parameters() if n.startswith("gru.weight_ih_l0")]
            out += [(self.self_anchor.copy_of(n), self.layout.columns("self")) for n in names]
        return out

    def output_columns(self) -> torch.Tensor:
        """No output of the trunk is an input passed through."""
        return no_columns(self.out_dim)

    # ----- forward -----
    def encode(self, groups: dict[str, torch.Tensor], frozen: dict[str, torch.Tensor] | None = None
               ) -> DetachFeatures:
        """`frozen`: z_env / z_self already computed by the frozen encoders on these inputs
        (`DetachModel.frozen_features`), used instead of running the encoders again."""
        x_env, x_self = groups["env"], groups["self"]
        frozen = frozen or {}
        z_env = frozen["z_env"] if "z_env" in frozen else (self.env_encoder(x_env) if self.env_encoder else None)
        f_env = self.proj_env(z_env if z_env is not None else x_env)
        z_self = frozen["z_self"] if "z_self" in frozen else (self.self_encoder(x_self) if self.self_encoder else None)
        f_self = self.proj_self(z_self if z_self is not None else x_self)
        fusion = self.fusion(f_env, f_self)
        return DetachFeatures(
            z_env if z_env is not None else f_env, z_self if z_self is not None else f_self, f_env, f_self, fusion
        )

    def tokens(self, groups: dict[str, torch.Tensor], fused: torch.Tensor) -> torch.Tensor:
        """[N, n_tokens, d]: fused step tokens, task token, extra-group tokens, + positions."""
        parts = [fused, self.task_token(groups["task"]).unsqueeze(1)]
        parts += [self.extra_tokens[g](groups[g]).unsqueeze(1) for g in self.layout.extra_groups]
        return torch.cat(parts, dim=1) + self.pos

    def latent(self, groups: dict[str, torch.Tensor], feats: DetachFeatures) -> torch.Tensor:
        """φ over the tokens, flattened: [N, out_dim]."""
        return self.transformer(self.tokens(groups, feats.fusion.fused)).flatten(1)

    def forward(self, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        return self.latent(groups, self.encode(groups))

    # ----- auxiliary losses -----
    def temporal_prediction_loss(self, x_self: torch.Tensor) -> torch.Tensor:
        """L_self = ‖Φ_self(obs^{t+1}) - f_pred(Φ_self(obs^t))‖².

        obs^t is the history window ending one step before the newest (steps 0..T-2), obs^{t+1}
        the window ending at the newest (1..T-1); each is summarised by the time-mean of z_self.
        A per-step target inside one window would leak through the backward GRU direction. The
        target is detached (stop-gradient, as in SimSiam/BYOL) to slow collapse.
        """
        if self.self_encoder is None or self.predictor is None or x_self.shape[1] < 2:
            return x_self.new_zeros(())
        z = self.self_encoder(torch.cat([x_self[:, :-1], x_self[:, 1:]], dim=0)).mean(1)
        z_prev, z_next = z.chunk(2, dim=0)
        return losses.mse(self.predictor(z_prev), z_next.detach())

    def aux_losses(
        self, groups: dict[str, torch.Tensor], reg: RegularizerCfg, feats: DetachFeatures | None = None
    ) -> dict[str, torch.Tensor]:
        """Every DETACH term as an unweighted scalar (see `DetachModel.aux_losses`); `feats`
        reuses the encoder/fusion outputs of a forward pass on the same groups."""
        x_env, x_self = groups["env"], groups["self"]
        feats = self.encode(groups) if feats is None else feats
        fo = feats.fusion
        zero = x_env.new_zeros(())
        rec_env = losses.mse(self.env_decoder(feats.z_env), x_env) if self.env_decoder else zero
        rec_self = losses.mse(self.self_decoder(feats.z_self), x_self) if self.self_decoder else zero
        z_env, z_self = feats.z_env.mean(1), feats.z_self.mean(1)
        mi = losses.gaussian_mi(z_env, z_self)
        r1 = (losses.param_l2(self.env_encoder.parameters(), self.env_anchor.anchors())
              if self._anchored("env") else None)
        r2 = (losses.param_l2(self.self_encoder.parameters(), self.self_anchor.anchors())
              if self._anchored("self") else None)
        return {
            "L_env": rec_env,
            "L_self": self.temporal_prediction_loss(x_self),
            "R_decouple": losses.r_decouple(z_env, z_self),
            "MI": mi,
            "R_temporal": losses.temporal_consistency(feats.z_self) if self.self_encoder else zero,
            "R_semantic_env": rec_env,
            "R_semantic_self": rec_self,
            "R_semantic": reg.semantic_env_weight * rec_env + reg.semantic_self_weight * rec_self,
            "L_fusion_quality": losses.fusion_consistency(fo.cross, fo.env_aligned, feats.f_self)
            + reg.lambda_disentangle * mi,
            "R1": r1 if r1 is not None else zero,
            "R2": r2 if r2 is not None else zero,
            "R3": losses.fusion_diversity([fo.cross, fo.gate, fo.moe], reg.r3_mode),
        }

    # ----- parameter groups for the progressive protocol -----
    def _anchored(self, stream: str) -> bool:
        anchor = self.env_anchor if stream == "env" else self.self_anchor
        return anchor is not None and bool(anchor.valid)

    def encoder_modules(self) -> list[nn.Module]:
        """Φ_env and Φ_self (whichever exist): θ_env, θ_self of the paper."""
        return [m for m in (self.env_encoder, self.self_encoder) if m is not None]

    def pretrain_head_modules(self) -> list[nn.Module]:
        """Decoder_env, Decoder_self, f_pred: trained only by the auxiliary losses."""
        return [m for m in (getattr(self, n) for n in PRETRAIN_HEADS) if m is not None]

    def fusion_parameters(self) -> Iterator[nn.Parameter]:
        """P_env, P_self, the fusion module, the task/extra tokens, positions and φ."""
        for m in (self.proj_env, self.proj_self, self.fusion, self.task_token, self.extra_tokens, self.transformer):
            yield from m.parameters()
        yield self.pos

    def training_only_modules(self) -> list[str]:
        """Names of the pre-training heads and R1/R2's anchors: read by the losses, never by
        the latent (about 30% of DETACH's actor at the default sizes)."""
        return [n for n in (*PRETRAIN_HEADS, *ANCHORS) if getattr(self, n) is not None]

    def snapshot_encoders(self) -> None:
        """Store θ*_env, θ*_self (end of pre-training) for R1/R2."""
        if self.env_encoder is not None:
            self.env_anchor.store(self.env_encoder)
        if self.self_encoder is not None:
            self.self_anchor.store(self.self_encoder)


class DetachModel(StructuredModel):
    """DETACH (and its ablations A1/A2 through `use_env_encoder` / `use_self_encoder`).

    Trainer API for the 3-stage protocol:
        aux_losses(obs, reuse_forward=False) -> {name: scalar}: unweighted terms on the same
            normalised inputs as forward; runs encoders + fusion again (never φ). With
            reuse_forward=True and the very TensorDict object of the last training-mode forward
            pass with grad (a PPO update: actor(batch.observations, ...), then
            actor.aux_losses(batch.observations, reuse_forward=True), then ONE backward of
            PPO loss + aux loss) it reuses that pass's encoder and fusion outputs instead,
            saving ~1/3 of the aux cost; do not use it if that forward's graph was already
            backpropagated. Terms:
            L_env (Decoder_env reconstruction), L_self (temporal prediction), R_decouple
            (‖Corr(z_env, z_self)‖_F²), MI (correlation-based I(z_env, z_self)), R_temporal,
            R_semantic_env, R_semantic_self, R_semantic (α/β-weighted sum), L_fusion_quality
            (‖f_cross - (f_env + f_self)‖² + λ_disentangle·MI), R1, R2 (‖θ - θ*‖², 0 before
            `snapshot_encoders`), R3 (fusion diversity, `regularizers.r3_mode`). Terms whose
            module an ablation removed are 0; the keys are always the same.
        aux_loss(obs, stage, reuse_forward=False) -> scalar: the weighted sum for stage
            pretrain | fusion | joint
            (see `losses.combine_aux_losses`).
        encoder_parameters(), pretrain_parameters(), fusion_parameters(), head_parameters()
        freeze_encoders(), unfreeze_encoders(), snapshot_encoders(), load_encoders_from(other)
    Pre-training without PPO: call `update_normalization(obs)` yourself so the inputs are
    normalised as they will be during RL.
    """

    trunk_class = DetachTrunk
    config_class = DetachCfg
    trunk: DetachTrunk
    _forward_cache: tuple[TensorDict, dict[str, torch.Tensor], DetachFeatures] | None = None

    def trunk_latent(self, obs: TensorDict, groups: dict[str, torch.Tensor]) -> torch.Tensor:
        feats = self.trunk.encode(groups, self._attached_features(obs))
        # Keep the encoder/fusion outputs of a training forward pass for aux_losses on the same obs.
        self._forward_cache = (obs, groups, feats) if torch.is_grad_enabled() and self.training else None
        return self.trunk.latent(groups, feats)

    def aux_losses(self, obs: TensorDict, reuse_forward: bool = False) -> dict[str, torch.Tensor]:
        cache, self._forward_cache = self._forward_cache, None
        if reuse_forward and cache is not None and cache[0] is obs:
            return self.trunk.aux_losses(cache[1], self.cfg.regularizers, cache[2])
        groups = self.normalized_groups(obs)
        feats = self.trunk.encode(groups, self._attached_features(obs))
        return self.trunk.aux_losses(groups, self.cfg.regularizers, feats)

    # ----- frozen encoders (stage 2): computed once per update -----
    @torch.no_grad()
    def frozen_features(self, obs: TensorDict) -> TensorDict | None:
        """z_env and z_self of every sample of `obs` [B] while both encoders are frozen (stage 2),
        else None. A trainer attaches them to the rollout's observations under
        `frozen_features_key()` for the update, so PPO's epochs and the auxiliary pass read them
        instead of running the frozen encoders again on every mini-batch (the same numbers up to
        float summation order: the encoders see the same normalised inputs, the normaliser does
        not move during an update)."""
        encoders = self.trunk.encoder_modules()
        if not encoders or any(p.requires_grad for m in encoders for p in m.parameters()):
            return None
        groups = self.normalized_groups(obs)
        out = {}
        if self.trunk.env_encoder is not None:
            out["z_env"] = self.trunk.env_encoder(groups["env"])
        if self.trunk.self_encoder is not None:
            out["z_self"] = self.trunk.self_encoder(groups["self"])
        return TensorDict(out, batch_size=obs.batch_size)

    def _attached_features(self, obs: TensorDict) -> dict[str, torch.Tensor] | None:
        feats = obs.get(self.frozen_features_key(), None)
        return None if feats is None else dict(feats.items())

    def aux_loss(self, obs: TensorDict, stage: str, reuse_forward: bool = False) -> torch.Tensor:
        return combine_aux_losses(self.aux_losses(obs, reuse_forward), stage, self.cfg.regularizers)

    def encoder_parameters(self) -> Iterator[nn.Parameter]:
        """θ_env and θ_self (Φ_env, Φ_self)."""
        return chain.from_iterable(m.parameters() for m in self.trunk.encoder_modules())

    def pretrain_parameters(self) -> Iterator[nn.Parameter]:
        """Stage 1: the encoders plus Decoder_env, Decoder_self and f_pred."""
        mods = self.trunk.encoder_modules() + self.trunk.pretrain_head_modules()
        return chain.from_iterable(m.parameters() for m in mods)

    def fusion_parameters(self) -> Iterator[nn.Parameter]:
        """Stage 2 (besides the heads): P_env, P_self, fusion, tokens and φ."""
        return self.trunk.fusion_parameters()

    def freeze_encoders(self) -> None:
        """Stage 2: θ_env, θ_self get requires_grad=False (Adam skips params without grad)."""
        for p in self.encoder_parameters():
            p.requires_grad_(False)

    def unfreeze_encoders(self) -> None:
        for p in self.encoder_parameters():
            p.requires_grad_(True)

    def training_only_prefixes(self) -> tuple[str, ...]:
        return tuple(f"trunk.{name}." for name in self.trunk.training_only_modules())

    def snapshot_encoders(self) -> None:
        """Record θ*_env, θ*_self (call at the end of pre-training); R1/R2 measure drift from them."""
        self.trunk.snapshot_encoders()

    @torch.no_grad()
    def load_encoders_from(self, other: DetachModel) -> None:
        """Copy encoders, their pre-training heads and anchors from another DETACH model (actor -> critic)."""
        t, o = self.trunk, other.trunk
        for name in ("env_encoder", "self_encoder", *PRETRAIN_HEADS, *ANCHORS):
            mine, theirs = getattr(t, name), getattr(o, name)
            if (mine is None) != (theirs is None):
                raise ValueError(f"cannot copy {name}: present in only one of the two models")
            if mine is not None:
                mine.load_state_dict(theirs.state_dict())


register_model(DetachModel, labels={"ablation_a1": "A1 (w/o env encoder)", "ablation_a2": "A2 (w/o self encoder)",
                                    "detach": "DETACH"},
               paper_labels={"ablation_a1": "A1", "ablation_a2": "A2"})
