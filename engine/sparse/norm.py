"""Normalisation and activation on sparse voxel features."""

from __future__ import annotations

from torch import nn

from .tensor import SparseVoxels


class SparseBatchNorm(nn.BatchNorm1d):
    """``nn.BatchNorm1d`` over the (N, C) features of the active voxels only (torchsparse ``spnn.BatchNorm``).

    Inactive voxels do not exist in the feature matrix, so batch statistics are over active voxels
    of all batch elements together. Subclassing keeps the parameter and buffer names
    (weight, bias, running_mean, running_var, num_batches_tracked) of the official checkpoint.
    """

    def forward(self, x: SparseVoxels) -> SparseVoxels:  # type: ignore[override]
        return x.replace_feats(super().forward(x.feats))


class SparseReLU(nn.ReLU):
    """ReLU on the features; ``inplace=True`` as torchsparse's SPVCNN uses it, to save memory."""

    def forward(self, x: SparseVoxels) -> SparseVoxels:  # type: ignore[override]
        return x.replace_feats(super().forward(x.feats))
