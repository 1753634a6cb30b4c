"""Project voxels into every view and sample the 2D feature maps there.

Conventions (official VoRTX, spec section 1):
- A voxel's world position is its corner, `index * voxel_size + origin` (the caller passes points).
- The intrinsics are scaled to the feature map by 1/stride with no half-pixel correction.
- The sampling grid is `(2u / (W_f - 1) - 1, 2v / (H_f - 1) - 1)` with u, v in feature pixels, so
  grid_sample runs with align_corners=True (bilinear, reflection padding).
- A projection is valid when both |grid| <= 1 and z > 0. No depth limit and no occlusion test.
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

from ..geometry.cameras import intrinsics_at_stride, project_points_torch

# Grid value for projections that are not finite: outside [-1, 1], hence invalid.
OUTSIDE = -2.0


@dataclass
class Projection:
    """Voxels seen from every view; M voxels, V views (voxel-major, like the fusion inputs).

    grid:   (M, V, 2) feature-map sampling coordinates in [-1, 1] when inside (align_corners=True).
    pixels: (M, V, 2) the same point in image pixels (u right, v down; the convention of K).
    depth:  (M, V) camera-space z in metres (may be <= 0 behind the camera).
    valid:  (M, V) bool, inside the image and in front of the camera.
    """

    grid: torch.Tensor
    pixels: torch.Tensor
    depth: torch.Tensor
    valid: torch.Tensor


def project_to_feature_maps(
    points: torch.Tensor,
    K: torch.Tensor,
    cam_to_world: torch.Tensor,
    stride: int,
    feature_hw: tuple[int, int],
) -> Projection:
    """points (M, 3) world metres; K (V, 3, 3) in image pixels; cam_to_world (V, 4, 4); feature map
    (H_f, W_f) at 1/stride of the image -> Projection."""
    u, v, z = project_points_torch(points, intrinsics_at_stride(K.to(points.dtype), stride), cam_to_world)
    uv = torch.stack([u, v], dim=-1)  # feature pixels
    h, w = feature_hw
    # max(.., 1) keeps a 1-pixel-wide map finite; its only valid coordinate is then 0 -> -1.
    scale = uv.new_tensor([2.0 / max(w - 1, 1), 2.0 / max(h - 1, 1)])
    grid = uv * scale - 1.0
    grid = torch.where(torch.isfinite(grid), grid, torch.full_like(grid, OUTSIDE))
    valid = (grid.abs() <= 1).all(dim=-1) & (z > 0)
    return Projection(grid=grid, pixels=uv * stride, depth=z, valid=valid)


def sample_features(feats: torch.Tensor, grid: torch.Tensor) -> torch.Tensor:
    """feats (V, C, H_f, W_f); grid (M, V, 2) -> (M, V, C) bilinear samples (reflection padding)."""
    sampled = F.grid_sample(
        feats,
        grid.transpose(0, 1)[:, None].to(feats.dtype),  # (V, 1, M, 2)
        mode="bilinear",
        padding_mode="reflection",
        align_corners=True,
    )  # (V, C, 1, M)
    return sampled[:, :, 0].permute(2, 0, 1)
