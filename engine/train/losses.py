"""VoRTX losses (vortx-spec.md section 3), every weight 1:

- coarse (16 cm) and medium (8 cm): BCE-with-logits occupancy, mean over predicted voxels that are
  in the supervised ground-truth set;
- fine (4 cm): L1 between log-transformed 1.05*tanh(logit) and the ground-truth TSDF;
- projective occupancy at every level: per (voxel, view) logit vs |z - depth| < 3*res, masked by
  valid projection and depth > 0, BCE over the pairs of EVERY sample of the batch. (The official
  code returns inside its batch loop and so supervises only sample 0; this is deliberately fixed.)

Predicted voxels are given by their level coordinates `[batch, x, y, z]` (level voxel units inside
the crop), so the lookup into the dense per-crop target grid is a plain index.
"""

from __future__ import annotations

import torch
import torch.nn.functional as F
from torch import Tensor

from ..model.outputs import tsdf_from_logits
from ..tsdf.targets import projective_occupancy_at_pixels


def logt(x: Tensor) -> Tensor:
    return torch.sign(x) * torch.log1p(x.abs())


def _zero(like: Tensor) -> Tensor:
    return like.sum() * 0.0  # keeps the graph, so DDP / backward see the parameters


def gather_targets(coords: Tensor, grid: Tensor, mask: Tensor) -> tuple[Tensor, Tensor]:
    """Targets and supervision mask (N,) of voxels `coords` (N, 4) [b, x, y, z] in (B, X, Y, Z)
    grids; voxels outside the grid are unsupervised."""
    b, x, y, z = coords.long().unbind(1)
    B, X, Y, Z = grid.shape
    inside = (b >= 0) & (b < B) & (x >= 0) & (x < X) & (y >= 0) & (y < Y) & (z >= 0) & (z < Z)
    bc, xc, yc, zc = b.clamp(0, B - 1), x.clamp(0, X - 1), y.clamp(0, Y - 1), z.clamp(0, Z - 1)
    return grid[bc, xc, yc, zc], mask[bc, xc, yc, zc] & inside


def occupancy_loss(logits: Tensor, coords: Tensor, occ: Tensor, mask: Tensor, balanced: bool = False) -> Tensor:
    """BCE-with-logits (mean) at predicted voxels in the supervised set.

    balanced=True weighs occupied voxels by n_empty / n_occupied (clamped to [1, 20]) - not in the
    spec (no pos_weight there); used to stop a short training from pruning every voxel."""
    target, sup = gather_targets(coords, occ, mask)
    logits = logits.reshape(-1)
    if not bool(sup.any()):
        return _zero(logits)
    t = target[sup].float()
    pos_weight = None
    if balanced:
        n_pos = t.sum()
        pos_weight = ((len(t) - n_pos) / n_pos.clamp(min=1)).clamp(1.0, 20.0).detach()
    return F.binary_cross_entropy_with_logits(logits[sup].float(), t, pos_weight=pos_weight)


def tsdf_loss(logits: Tensor, coords: Tensor, tsdf: Tensor, mask: Tensor) -> Tensor:
    """L1(logt(1.05 tanh(logit)), logt(gt)) (mean) at predicted voxels in the supervised set."""
    target, sup = gather_targets(coords, tsdf, mask)
    logits = logits.reshape(-1)
    if not bool(sup.any()):
        return _zero(logits)
    pred = tsdf_from_logits(logits[sup].float())  # the network's own rule, as inference reads it
    return F.l1_loss(logt(pred), logt(target[sup].float()))


def projective_occupancy_loss_batch(
    logits: Tensor, sample: Tensor, pixels: Tensor, depth: Tensor, valid: Tensor, depth_maps: Tensor, trunc: float
) -> Tensor:
    """Projective-occupancy BCE over every (voxel, view) pair of the whole batch at one level.

    logits, depth (N, V) and valid (N, V) bool from the network's prediction, pixels (N, V, 2) the
    (u, v) image position, sample (N,) each voxel's batch index; depth_maps (B, V, H, W) metres.
    Targets: `engine.tsdf.targets.projective_occupancy_at_pixels` with each voxel's own sample's
    depth maps; supervised where also valid. One mean over all samples (the official code's early
    return supervised sample 0 only)."""
    target, sup = projective_occupancy_at_pixels(pixels, depth, depth_maps, trunc, sample)
    sup = sup & valid.bool()
    if not bool(sup.any()):
        return _zero(logits)
    return F.binary_cross_entropy_with_logits(logits[sup].float(), target[sup])
