"""DETACH's auxiliary losses and regularisers as pure functions returning scalars.

Conventions (so the paper's λ values act on comparable scales): squared errors ‖a - b‖² are
means over batch, time and features (MSE); sums over time steps in the paper (Σ_t) are means
too. Correlation/MI terms act on per-sample vectors [N, D] (time-mean of z sequences), with the
correlation taken across the batch, and are means over the feature pairs. Parameter
preservation (R1, R2) is a plain sum of squared differences, as printed.
"""

from __future__ import annotations

from collections.abc import Iterable, Mapping

import torch
import torch.nn.functional as F

from detach.models.configs import RegularizerCfg

STAGES: tuple[str, ...] = ("pretrain", "fusion", "joint")


def mse(a: torch.Tensor, b: torch.Tensor) -> torch.Tensor:
    return F.mse_loss(a, b)


def correlation_matrix(a: torch.Tensor, b: torch.Tensor, eps: float = 1e-6) -> torch.Tensor:
    """Pearson correlations between the columns of a [N, Da] and b [N, Db] -> [Da, Db].

    Constant columns (zero variance) get correlation 0 rather than NaN.
    """
    a = a - a.mean(0, keepdim=True)
    b = b - b.mean(0, keepdim=True)
    a = a / (a.pow(2).mean(0, keepdim=True).sqrt() + eps)
    b = b / (b.pow(2).mean(0, keepdim=True).sqrt() + eps)
    return a.transpose(0, 1) @ b / a.shape[0]


def r_decouple(z_env: torch.Tensor, z_self: torch.Tensor) -> torch.Tensor:
    """R_decouple = ‖Corr(z_env, z_self)‖_F² on [N, D] features, as a mean over the Da·Db
    feature pairs (the module's convention). As a sum it was 150-900 for 64-wide codes, so
    λ_decouple·R_decouple outweighed PPO's loss ~30:1 in the joint stage and Carry stalled."""
    return correlation_matrix(z_env, z_self).pow(2).mean()


def gaussian_mi(z_env: torch.Tensor, z_self: torch.Tensor, max_rho2: float = 0.9999) -> torch.Tensor:
    """Correlation-based MI estimate I ≈ -½ mean_ij log(1 - ρ_ij²) (nats per feature pair).

    Exact for a jointly Gaussian pair; taking it pair by pair ignores the joint structure (no
    covariance inversion, so it stays stable for small batches and singular covariances). A
    mean over pairs, as `r_decouple`, so that λ_disentangle does not scale with the code width.
    """
    rho2 = correlation_matrix(z_env, z_self).pow(2).clamp(max=max_rho2)
    return -0.5 * torch.log1p(-rho2).mean()


def temporal_consistency(z_seq: torch.Tensor) -> torch.Tensor:
    """R_temporal = mean_t ‖z^{t+1} - z^t‖² over a [N, T, D] sequence (0 when T < 2)."""
    if z_seq.shape[1] < 2:
        return z_seq.sum() * 0.0
    return mse(z_seq[:, 1:], z_seq[:, :-1])


def fusion_consistency(f_cross: torch.Tensor, f_env: torch.Tensor, f_self: torch.Tensor) -> torch.Tensor:
    """First term of L_fusion_quality: ‖f_cross - (f_env + f_self)‖²."""
    return mse(f_cross, f_env + f_self)


def fusion_diversity(outputs: list[torch.Tensor], mode: str = "distance") -> torch.Tensor:
    """R3 over the fusion outputs (f_cross, f_gate, f_moe), each [..., d].

    `distance`: Σ_{i≠j} ‖f_i - f_j‖² exactly as printed (minimising it makes the strategies
    agree). `cosine`: mean over i≠j of the squared cosine similarity (minimising it makes them
    point in different directions, the stated intent "complementary representations").
    """
    total = outputs[0].sum() * 0.0
    for i, fi in enumerate(outputs):
        for j, fj in enumerate(outputs):
            if i == j:
                continue
            if mode == "distance":
                total = total + mse(fi, fj)
            elif mode == "cosine":
                n = len(outputs)
                total = total + F.cosine_similarity(fi, fj, dim=-1).pow(2).mean() / (n * (n - 1))
            else:
                raise ValueError(f"model.regularizers.r3_mode must be 'distance' or 'cosine', got {mode!r}")
    return total


def param_l2(params: Iterable[torch.Tensor], anchors: Iterable[torch.Tensor]) -> torch.Tensor | None:
    """R1/R2 = ‖θ - θ*‖² summed over all entries; None when there are no parameters."""
    total = None
    for p, a in zip(params, anchors, strict=True):
        d = (p - a).pow(2).sum()
        total = d if total is None else total + d
    return total


def combine_aux_losses(terms: Mapping[str, torch.Tensor], stage: str, reg: RegularizerCfg) -> torch.Tensor:
    """The weighted auxiliary loss of one stage of the progressive protocol (add it to L_task).

    - `pretrain` (encoders alone, no PPO): L_env + L_self + β·R_semantic_self. The self
      reconstruction is our addition: L_self alone is minimised by a constant z_self.
    - `fusion` (encoders frozen): λ_quality · L_fusion_quality (which already holds
      λ_disentangle·MI).
    - `joint`: λ_disentangle·MI + λ_r1·R1 + λ_r2·R2 + λ_r3·R3 + λ_decouple·R_decouple
      + λ_temporal·R_temporal + λ_semantic·R_semantic.
    """
    if stage == "pretrain":
        return terms["L_env"] + terms["L_self"] + reg.semantic_self_weight * terms["R_semantic_self"]
    if stage == "fusion":
        return reg.lambda_quality * terms["L_fusion_quality"]
    if stage == "joint":
        return (
            reg.lambda_disentangle * terms["MI"]
            + reg.lambda_r1 * terms["R1"]
            + reg.lambda_r2 * terms["R2"]
            + reg.lambda_r3 * terms["R3"]
            + reg.lambda_decouple * terms["R_decouple"]
            + reg.lambda_temporal * terms["R_temporal"]
            + reg.lambda_semantic * terms["R_semantic"]
        )
    raise ValueError(f"stage must be one of {STAGES}, got {stage!r}")
