"""Sparse voxel tensor: integer coordinates + per-voxel features + a shared cache.

Coordinate convention (torchsparse v1.4 style, batch first as in torchsparse v2):

- ``coords`` is (N, 4) int64 ``[batch, x, y, z]``. Coordinates are always expressed in units of the
  finest grid of the tensor's *level* (the grid of the tensor the U-Net was called on), never in
  units of the current grid. A tensor of ``stride`` s therefore has x, y, z that are multiples of s.
- Neighbours of a voxel at p in a stride-s tensor are at ``p + offset * s``, so kernel maps at every
  stride are built the same way, and a stride-2s parent is ``floor(p / 2s) * 2s``.
- Coordinates may be negative; batch indices are usually >= 0 but need not be.
- Each coordinate must occur at most once (kernel-map building checks this).

The cache is the equivalent of torchsparse's ``cmaps``/``kmaps`` dictionaries: every tensor derived
from the same input (feature replacement, convolutions, norms, additions) carries the *same*
``SparseCache`` object, so kernel maps are built once per stride and a transposed convolution can
return exactly onto the coordinate set (and order) of an earlier stride.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import TYPE_CHECKING, Sequence

import torch
from torch import Tensor

if TYPE_CHECKING:  # only for annotations; kernel_map imports this module
    from .kernel_map import KernelMap


@dataclass
class SparseCache:
    """State shared by all tensors derived from one input.

    coords: stride -> the (N_s, 4) coordinate tensor of that stride. The tensor object itself is
        stored (not a copy) so identity checks are free and row order is preserved.
    kernel_maps: (kind, stride, kernel_size) -> KernelMap, kind in {"submanifold", "downsample",
        "upsample"}; stride is the stride of the map's *input* tensor. An upsample map is the
        transposed downsample map of the next finer stride.
    """

    coords: dict[int, Tensor] = field(default_factory=dict)
    kernel_maps: dict[tuple[str, int, int], "KernelMap"] = field(default_factory=dict)


class SparseVoxels:
    """Active voxels of a (batched) sparse 3D grid.

    Attributes:
        coords: (N, 4) int64 ``[batch, x, y, z]``, multiples of ``stride`` in x, y, z (see module doc).
        feats: (N, C) features, row i belongs to ``coords[i]``.
        stride: int >= 1, the tensor stride in finest-grid units.
        cache: SparseCache shared with every tensor derived from the same input.
    """

    __slots__ = ("coords", "feats", "stride", "cache")

    def __init__(self, coords: Tensor, feats: Tensor, stride: int = 1, cache: SparseCache | None = None) -> None:
        if coords.dim() != 2 or coords.shape[1] != 4:
            raise ValueError(f"coords must be (N, 4) [batch, x, y, z], got shape {tuple(coords.shape)}")
        if coords.dtype != torch.int64:
            raise ValueError(f"coords must be int64, got {coords.dtype}")
        if feats.dim() != 2 or feats.shape[0] != coords.shape[0]:
            raise ValueError(f"feats must be (N, C) with N = {coords.shape[0]}, got shape {tuple(feats.shape)}")
        if coords.device != feats.device:
            raise ValueError(f"coords on {coords.device} but feats on {feats.device}")
        if int(stride) != stride or stride < 1:
            raise ValueError(f"stride must be a positive integer, got {stride}")
        stride = int(stride)
        if cache is None:
            cache = SparseCache()
        registered = cache.coords.setdefault(stride, coords)
        # Identity, not equality: cached kernel maps index rows of exactly this tensor, and an
        # element-wise comparison would cost a device sync on every feature replacement.
        if registered is not coords:
            raise ValueError(
                f"a different coordinate set is already cached for stride {stride}; build a new "
                "SparseVoxels without `cache` for a new coordinate set (e.g. after pruning)"
            )
        self.coords = coords
        self.feats = feats
        self.stride = stride
        self.cache = cache

    @property
    def num_voxels(self) -> int:
        return self.coords.shape[0]

    @property
    def num_channels(self) -> int:
        return self.feats.shape[1]

    @property
    def device(self) -> torch.device:
        return self.feats.device

    def replace_feats(self, feats: Tensor) -> "SparseVoxels":
        """Same coordinates, stride and cache with new (N, C') features."""
        return SparseVoxels(self.coords, feats, self.stride, self.cache)

    def same_coords(self, other: "SparseVoxels") -> bool:
        """True when both tensors index the same voxel rows (same cached coordinate tensor)."""
        return self.coords is other.coords and self.stride == other.stride

    def __add__(self, other: "SparseVoxels") -> "SparseVoxels":
        """Element-wise sum of features at identical coordinates (residual connections)."""
        _require_same_coords(self, other, "add")
        return self.replace_feats(self.feats + other.feats)

    def __repr__(self) -> str:
        return (
            f"SparseVoxels(num_voxels={self.num_voxels}, channels={self.num_channels}, stride={self.stride}, "
            f"dtype={self.feats.dtype}, device={self.device})"
        )


def cat_features(tensors: Sequence[SparseVoxels]) -> SparseVoxels:
    """Concatenate features along channels, in the given order: (N, C1 + C2 + ...).

    All tensors must share one coordinate set (like ``torchsparse.cat``); the U-Net uses this for
    ``cat[upsampled, skip]``.
    """
    if not tensors:
        raise ValueError("cat_features needs at least one tensor")
    first = tensors[0]
    for t in tensors[1:]:
        _require_same_coords(first, t, "concatenate")
    return first.replace_feats(torch.cat([t.feats for t in tensors], dim=1))


def _require_same_coords(a: SparseVoxels, b: SparseVoxels, what: str) -> None:
    if not a.same_coords(b):
        raise ValueError(
            f"cannot {what} sparse tensors with different coordinate sets "
            f"(strides {a.stride} and {b.stride}, {a.num_voxels} and {b.num_voxels} voxels)"
        )
