"""Training targets derived from a ground-truth TSDF (vortx-spec.md sections 2 and 3).

- Occupancy per level: occ_04 = |t| < .999, seen_04 = t < .999; the next level is a 3x3x3 dilation
  followed by a strided pick ([::2] on every axis), exactly like the official `data.py`.
- Supervised set: the seen voxels plus every voxel of a z-column that is entirely unobserved (the
  Atlas rule); those columns are supervised as +1 TSDF / not occupied.
- Projective occupancy: a voxel is "occupied" for a view when its camera depth is within 3 * res of
  the depth map there (the training loss reads it at the network's own projections).
All functions take and return torch tensors on the input's device (CPU or CUDA).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import torch
import torch.nn.functional as F

from ..geometry.cameras import project_points_torch

SEEN_LIMIT = 0.999  # |t| below this counts as "near a surface"; t below it counts as "seen"


@dataclass
class LevelTargets:
    """Targets of one level, all (X, Y, Z) bool at that level's resolution.

    occupied: voxel is (or, coarser, is next to) a surface; free: seen and not occupied;
    supervised: where a loss is taken (seen, or in a wholly unobserved z-column).
    """

    occupied: torch.Tensor
    free: torch.Tensor
    supervised: torch.Tensor

    @property
    def seen(self) -> torch.Tensor:
        return self.occupied | self.free


def unobserved_columns(seen: torch.Tensor) -> torch.Tensor:
    """(X, Y, Z) bool: voxels whose whole z-column (last axis) is unseen. seen: (X, Y, Z) bool."""
    return (~seen).all(dim=-1, keepdim=True).expand_as(seen)


def supervised_mask(tsdf: torch.Tensor) -> torch.Tensor:
    """Fine-level supervised set: seen (t < .999) or in a z-column with no seen voxel. tsdf: (X, Y, Z) float."""
    seen = tsdf < SEEN_LIMIT
    return seen | unobserved_columns(seen)


def dilate(mask: torch.Tensor) -> torch.Tensor:
    """3x3x3 binary dilation of (X, Y, Z) bool; outside the grid counts as False (skimage's rule)."""
    x = mask[None, None].float()
    return F.max_pool3d(x, kernel_size=3, stride=1, padding=1)[0, 0] > 0


def occupancy_targets(tsdf: torch.Tensor) -> dict[str, LevelTargets]:
    """Targets for the three levels from the fine TSDF (X, Y, Z) (ground-truth convention).

    Returns {"fine": 4 cm, "medium": 8 cm, "coarse": 16 cm}; medium/coarse have shape
    ceil(shape / 2) and ceil(shape / 4). "fine" `occupied` is |t| < .999 (its TSDF is the real target).
    """
    occ = tsdf.abs() < SEEN_LIMIT
    seen = tsdf < SEEN_LIMIT
    levels = {"fine": LevelTargets(occ, seen & ~occ, supervised_mask(tsdf))}
    for name in ("medium", "coarse"):
        dilated = dilate(occ)
        # The official code dilates at the finer level and then picks every other voxel.
        occ = dilated[::2, ::2, ::2]
        free = (seen & ~dilated)[::2, ::2, ::2]
        seen = occ | free
        levels[name] = LevelTargets(occ, free, seen | unobserved_columns(seen))
    return levels


def projective_occupancy_at_pixels(
    pixels: torch.Tensor, depth: torch.Tensor, depth_maps: torch.Tensor, trunc: float,
    sample: Optional[torch.Tensor] = None,
) -> tuple[torch.Tensor, torch.Tensor]:
    """Projective-occupancy targets of N voxels seen in V views.

    pixels (N, V, 2) the voxels' image positions (u, v); depth (N, V) their camera z; depth_maps
    (B, V, H, W) metres, 0 = missing, in pixels of the images K refers to; sample (N,) each voxel's
    batch index (None when B = 1). The map is read at the pixel holding (u, v): floor, since pixel j
    covers [j, j + 1) (the engine's K convention). Returns (target (N, V) float, 1 where |z - d| <
    trunc; supervised (N, V) bool: inside the image, z > 0 and d > 0).
    """
    _, V, H, W = depth_maps.shape
    ui = torch.floor(pixels[..., 0]).long()
    vi = torch.floor(pixels[..., 1]).long()
    inside = (ui >= 0) & (ui < W) & (vi >= 0) & (vi < H) & (depth > 0)
    b = torch.zeros_like(ui) if sample is None else sample.long()[:, None].expand_as(ui)
    view = torch.arange(V, device=depth_maps.device)[None, :].expand_as(ui)
    d = depth_maps[b, view, vi.clamp(0, H - 1), ui.clamp(0, W - 1)]
    return ((depth - d).abs() < trunc).float(), inside & (d > 0)


def projective_occupancy(
    points: torch.Tensor, K: torch.Tensor, cam_to_world: torch.Tensor, depth_maps: torch.Tensor, trunc: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """`projective_occupancy_at_pixels` for world points (M, 3) in views K (V, 3, 3), cam_to_world
    (V, 4, 4) with depth maps (V, H, W): (target (M, V) float, supervised (M, V) bool). The spec's
    truncation is 3 voxels of the level (`trunc` = 3 * res)."""
    u, v, z = project_points_torch(points, K, cam_to_world)
    return projective_occupancy_at_pixels(torch.stack([u, v], dim=-1), z, depth_maps[None], trunc)
