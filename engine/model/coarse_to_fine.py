"""Coarse-to-fine voxel bookkeeping: nearest 2x upsampling and per-sample voxel dropout.

Coordinates are (N, 4) int64 `[batch, x, y, z]` in units of a level's own voxels, so voxel i of one
level has the children 2i + {0,1}^3 at the next (finer) level.
"""

from __future__ import annotations

import torch
from torch import nn

# Child offsets in [batch, x, y, z], in the official Upsampler's order of (x, y, z).
CHILD_OFFSETS = (
    (0, 0, 0, 0),
    (0, 1, 0, 0),
    (0, 0, 1, 0),
    (0, 0, 0, 1),
    (0, 1, 1, 0),
    (0, 0, 1, 1),
    (0, 1, 0, 1),
    (0, 1, 1, 1),
)
CHILD_SCALE = (1, 2, 2, 2)


class Upsampler(nn.Module):
    """Nearest-neighbour 2x upsampling of a sparse voxel set.

    The official model keeps the offsets and multipliers as (frozen) tensors; they are buffers
    here with the same names and shapes, `upsample_offsets` (1, 8, 4) and `upsample_mul` (1, 1, 4),
    but in this engine's `[batch, x, y, z]` column order (the official order is `[x, y, z, batch]`).
    """

    def __init__(self) -> None:
        super().__init__()
        self.register_buffer("upsample_offsets", torch.tensor([CHILD_OFFSETS], dtype=torch.int32))
        self.register_buffer("upsample_mul", torch.tensor([[CHILD_SCALE]], dtype=torch.int32))

    def upsample_coords(self, coords: torch.Tensor) -> torch.Tensor:
        """(N, 4) parents -> (8N, 4) children; the 8 children of parent i are rows 8i..8i+7."""
        children = coords[:, None, :] * self.upsample_mul.long() + self.upsample_offsets.long()
        return children.reshape(-1, 4)

    @staticmethod
    def upsample_values(values: torch.Tensor) -> torch.Tensor:
        """(N, ...) per-parent values -> (8N, ...) copied to each child, rows aligned with upsample_coords."""
        return values.repeat_interleave(8, dim=0)


def subsample_per_sample(coords: torch.Tensor, max_per_sample: int, generator: torch.Generator | None = None) -> torch.Tensor:
    """Row indices keeping at most `max_per_sample` random voxels of each batch sample.

    coords (N, 4) [batch, ...] -> (N',) int64 ascending (so rows stay grouped as they were).
    """
    keep = []
    for b in torch.unique(coords[:, 0]):
        rows = torch.nonzero(coords[:, 0] == b).view(-1)
        if len(rows) > max_per_sample:
            pick = torch.randperm(len(rows), generator=generator, device="cpu")[:max_per_sample]
            rows = rows[pick.to(rows.device)]
        keep.append(rows)
    if not keep:
        return torch.zeros(0, dtype=torch.long, device=coords.device)
    return torch.sort(torch.cat(keep)).values
