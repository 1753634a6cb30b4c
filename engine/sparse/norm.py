"""Normalisation and activation on sparse voxel features."""

from __future__ import annotations

import torch.nn.functional as F
from torch import nn

from .tensor import SparseVoxels


class SparseBatchNorm(nn.BatchNorm1d):
    """``nn.BatchNorm1d`` over the (N, C) features of the active voxels only (torchsparse ``spnn.BatchNorm``).

    Inactive voxels do not exist in the feature matrix, so batch statistics are over active voxels
    of all batch elements together. Subclassing keeps the parameter and buffer names
    (weight, bias, running_mean, running_var, num_batches_tracked) of the official checkpoint.

    scene_statistics: in eval mode, normalise with the statistics of the voxels passed in (at
    inference: the whole scene's active voxels at this level) instead of the running averages, and
    leave the running averages untouched. Training mode is unaffected.

    Fewer than two voxels have no batch statistics (a training crop whose pruned level collapsed):
    they are normalised with the running averages, which stay as they are, so training goes on
    with the same step on every DDP rank instead of failing.
    """

    scene_statistics: bool = False

    def forward(self, x: SparseVoxels) -> SparseVoxels:  # type: ignore[override]
        if len(x.feats) < 2:
            normalised = F.batch_norm(x.feats, self.running_mean, self.running_var, self.weight, self.bias,
                                      training=False, eps=self.eps)
        elif self.training or not self.scene_statistics:
            normalised = super().forward(x.feats)
        else:
            normalised = F.batch_norm(x.feats, None, None, self.weight, self.bias, training=True, eps=self.eps)
        return x.replace_feats(normalised)


class SparseReLU(nn.ReLU):
    """ReLU on the features; ``inplace=True`` as torchsparse's SPVCNN uses it, to save memory."""

    def forward(self, x: SparseVoxels) -> SparseVoxels:  # type: ignore[override]
        return x.replace_feats(super().forward(x.feats))
