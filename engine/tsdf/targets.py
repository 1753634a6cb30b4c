"""Training targets derived from a ground-truth TSDF (vortx-spec.md sections 2 and 3).

- Occupancy per level: occ_04 = |t| < .999, seen_04 = t < .999; the next level is a 3x3x3 dilation
  followed by a strided pick ([::2] on every axis), exactly like the official `data.py`.
- Supervised set: the seen voxels plus every voxel of a z-column that is entirely unobserved (the
  Atlas rule); those columns are supervised as +1 TSDF / not occupied.
- Projective occupancy: a voxel is "occupied" for a view when its camera depth is within 3 * res of
  the depth map there.
All functions take and return torch tensors on the input's device (CPU or CUDA).
"""

from __future__ import annotations

from dataclasses import dataclass

import torch
import torch.nn.functional as F

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
    """Fine-level supervised set: (t < .999) | column entirely > .999. tsdf: (X, Y, Z) float."""
    return (tsdf < SEEN_LIMIT) | (tsdf > SEEN_LIMIT).all(dim=-1, keepdim=True).expand_as(tsdf)


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


def sample_depth_nearest(
    points: torch.Tensor, depth: torch.Tensor, K: torch.Tensor, cam_to_world: torch.Tensor
) -> tuple[torch.Tensor, torch.Tensor, torch.Tensor]:
    """Project world points into one view and read the depth map at the pixel they fall in.

    points (M, 3); depth (H, W) metres, 0 = missing; K (3, 3) with pixel (0, 0) covering [0, 1)^2
    (the engine's convention, so the pixel holding u is floor(u)); cam_to_world (4, 4).
    Returns (z (M,) camera depth of the points, d (M,) depth-map value, valid (M,) bool: in front of
    the camera, inside the image and d > 0).
    """
    R, t = cam_to_world[:3, :3].to(points.dtype), cam_to_world[:3, 3].to(points.dtype)
    cam = (points - t) @ R
    z = cam[:, 2]
    z_safe = torch.where(z > 0, z, torch.ones_like(z))
    u = torch.floor(cam[:, 0] / z_safe * K[0, 0] + K[0, 2])
    v = torch.floor(cam[:, 1] / z_safe * K[1, 1] + K[1, 2])
    height, width = depth.shape
    inside = (z > 0) & (u >= 0) & (u < width) & (v >= 0) & (v < height)
    d = depth[torch.where(inside, v, torch.zeros_like(v)).long(), torch.where(inside, u, torch.zeros_like(u)).long()]
    d = torch.where(inside, d, torch.zeros_like(d))
    return z, d, inside & (d > 0)


def projective_occupancy(
    points: torch.Tensor, depth: torch.Tensor, K: torch.Tensor, cam_to_world: torch.Tensor, voxel_size: float
) -> tuple[torch.Tensor, torch.Tensor]:
    """Projective-occupancy target of points for one view: (target (M,) bool |z - d| < 3 * voxel_size,
    valid (M,) bool where the loss applies). Shapes as in `sample_depth_nearest`."""
    z, d, valid = sample_depth_nearest(points, depth, K, cam_to_world)
    return ((z - d).abs() < 3 * voxel_size) & valid, valid
