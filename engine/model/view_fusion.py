"""Multi-view fusion: per voxel, combine the features back-projected from V views into one.

`TransformerFusion` is VoRTX's `MVFusionTransformer`:
1. depth-aware input `Linear(C+1 -> C)` on [f_v, (z_v - 1.85) / 0.85] (no activation);
2. a pre-LN transformer over the views of each voxel (2 layers, 2 heads, MLP 2C ReLU, dropout 0,
   no final LN); invalid views are masked as keys, the diagonal stays open so every row of the
   attention has at least one entry;
3. a per-view projective-occupancy logit `Linear(C -> 1)`;
4. pooling: masked mean (training phase 1) or softmax over the logits with a null view (logit 0,
   zero feature) appended, invalid views at -9e3 - a voxel no view sees fuses to exactly zero.

With stereo evidence (VortxConfig.stereo_evidence), each view's token also gets `Linear(3 -> C)` of
[projective signed distance, confidence, valid] added after the depth-aware input layer, so the
transformer and the projective-occupancy logits can weigh views by whether their depth agrees.

`AverageFusion` is the averaging ablation: masked mean of the raw back-projected features.
Module and parameter names match the official checkpoint (`transformer.encoder_layers.<i>.attn.
in_proj_weight`, `depth_mlp`, `proj_tsdf_mlp`, ...). Shapes: M voxels, V views, C channels.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import nn

# Normalisation of the camera depth fed to the depth-aware input layer (official constants).
DEPTH_MEAN = 1.85
DEPTH_STD = 0.85
# Logit given to invalid views before the softmax: exp(-9e3) is exactly 0 in float32 and float16.
INVALID_LOGIT = -9e3


def masked_mean_pool(features: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """features (M, V, C), valid (M, V) -> (M, C) mean over valid views; 0 where none is valid."""
    # where(), not multiply: features of invalid views may be anything, including inf.
    kept = torch.where(valid[..., None], features, torch.zeros_like(features))
    count = valid.sum(dim=1, keepdim=True).clamp(min=1).to(features.dtype)
    return kept.sum(dim=1) / count


def softmax_null_pool(features: torch.Tensor, logits: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
    """Softmax-with-null pooling. features (M, V, C), logits (M, V), valid (M, V) -> (M, C).

    A null view with logit 0 and a zero feature joins the softmax, so a voxel whose views all predict
    "not near the surface" (very negative logits) - or that no view sees - fuses to ~0 / exactly 0.
    """
    logits = logits.masked_fill(~valid, INVALID_LOGIT)
    null = logits.new_zeros(logits.shape[0], 1)
    weights = torch.softmax(torch.cat([logits, null], dim=1), dim=1)[:, :-1]  # the null feature is 0
    kept = torch.where(valid[..., None], features, torch.zeros_like(features))
    return torch.einsum("mv,mvc->mc", weights, kept)


class ViewAttention(nn.Module):
    """Multi-head self-attention over views, parameter-compatible with `nn.MultiheadAttention`
    (`in_proj_weight`, `in_proj_bias`, `out_proj`) but batch-first with a broadcast mask, so the
    mask is not materialised once per head."""

    def __init__(self, channels: int, num_heads: int) -> None:
        super().__init__()
        self.num_heads = num_heads
        self.in_proj_weight = nn.Parameter(torch.empty(3 * channels, channels))
        self.in_proj_bias = nn.Parameter(torch.zeros(3 * channels))
        self.out_proj = nn.Linear(channels, channels)
        # nn.MultiheadAttention's initialisation.
        nn.init.xavier_uniform_(self.in_proj_weight)
        nn.init.zeros_(self.out_proj.bias)

    def forward(self, x: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
        """x (M, V, C); allowed (M, V, V) bool, [m, i, j] = query i may attend key j -> (M, V, C)."""
        m, v, c = x.shape
        head_dim = c // self.num_heads
        q, k, val = F.linear(x, self.in_proj_weight, self.in_proj_bias).chunk(3, dim=-1)
        q, k, val = (t.reshape(m, v, self.num_heads, head_dim).transpose(1, 2) for t in (q, k, val))
        out = F.scaled_dot_product_attention(q, k, val, attn_mask=allowed[:, None])  # (M, h, V, hd)
        return self.out_proj(out.transpose(1, 2).reshape(m, v, c))


class MlpBlock(nn.Module):
    def __init__(self, channels: int, hidden: int) -> None:
        super().__init__()
        self.fc1 = nn.Linear(channels, hidden)
        self.fc2 = nn.Linear(hidden, channels)
        for fc in (self.fc1, self.fc2):
            nn.init.kaiming_normal_(fc.weight)
            nn.init.zeros_(fc.bias)

    def forward(self, x: torch.Tensor) -> torch.Tensor:
        return self.fc2(F.relu(self.fc1(x)))


class EncoderBlock(nn.Module):
    """Pre-LN block: x + MHA(LN x), then x + MLP(LN x)."""

    def __init__(self, channels: int, num_heads: int) -> None:
        super().__init__()
        self.norm1 = nn.LayerNorm(channels)
        self.attn = ViewAttention(channels, num_heads)
        self.norm2 = nn.LayerNorm(channels)
        self.mlp = MlpBlock(channels, 2 * channels)

    def forward(self, x: torch.Tensor, allowed: torch.Tensor) -> torch.Tensor:
        x = x + self.attn(self.norm1(x), allowed)
        return x + self.mlp(self.norm2(x))


class ViewTransformer(nn.Module):
    def __init__(self, channels: int, num_layers: int, num_heads: int) -> None:
        super().__init__()
        self.encoder_layers = nn.ModuleList(EncoderBlock(channels, num_heads) for _ in range(num_layers))

    def forward(self, x: torch.Tensor, valid: torch.Tensor) -> torch.Tensor:
        """x (M, V, C); valid (M, V) -> (M, V, C). Invalid views are masked as keys only."""
        v = x.shape[1]
        eye = torch.eye(v, dtype=torch.bool, device=x.device)
        allowed = valid[:, None, :] | eye  # (M, V, V)
        for layer in self.encoder_layers:
            x = layer(x, allowed)
        return x


class TransformerFusion(nn.Module):
    """VoRTX view fusion. forward -> (pooled (M, C), proj-occ logits (M, V))."""

    def __init__(self, channels: int, num_layers: int, num_heads: int, evidence_channels: int = 0) -> None:
        super().__init__()
        self.transformer = ViewTransformer(channels, num_layers, num_heads)
        self.depth_mlp = nn.Linear(channels + 1, channels)
        self.proj_tsdf_mlp = nn.Linear(channels, 1)
        # A separate layer (not a wider depth_mlp) keeps the official checkpoint's parameter names.
        self.evidence_mlp = nn.Linear(evidence_channels, channels) if evidence_channels else None
        for layer in (self.depth_mlp, self.proj_tsdf_mlp, self.evidence_mlp):
            if layer is not None:
                nn.init.kaiming_normal_(layer.weight)
                nn.init.zeros_(layer.bias)

    def forward(
        self, features: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor, use_proj_occ: bool,
        evidence: torch.Tensor | None = None,
    ) -> tuple[torch.Tensor, torch.Tensor]:
        """features (M, V, C), depth (M, V) camera z, valid (M, V), evidence (M, V, E) when the module
        was built with E evidence channels -> ((M, C), (M, V))."""
        if (evidence is None) != (self.evidence_mlp is None):
            raise ValueError("stereo evidence must be given exactly when the fusion was built for it")
        z = ((depth - DEPTH_MEAN) / DEPTH_STD).to(features.dtype)
        x = self.depth_mlp(torch.cat([features, z[..., None]], dim=-1))
        if evidence is not None:
            x = x + self.evidence_mlp(evidence.to(x.dtype))
        x = self.transformer(x, valid)
        logits = self.proj_tsdf_mlp(x)[..., 0]
        pooled = softmax_null_pool(x, logits, valid) if use_proj_occ else masked_mean_pool(x, valid)
        return pooled, logits


class AverageFusion(nn.Module):
    """Averaging ablation: no parameters, no projective occupancy."""

    def forward(
        self, features: torch.Tensor, depth: torch.Tensor, valid: torch.Tensor, use_proj_occ: bool,
        evidence: None = None,
    ) -> tuple[torch.Tensor, None]:
        return masked_mean_pool(features, valid), None
