"""Sparse voxel tensors and torchsparse-v1.4-compatible sparse convolution in pure PyTorch.

Coordinates are (N, 4) int64 ``[batch, x, y, z]`` in units of the level's finest grid; a tensor of
stride s has x, y, z that are multiples of s (see ``tensor.py``). No compiled extension: runs on CPU
and CUDA alike.
"""

from .conv import SparseConv3d, conv3d, sparse_conv_features
from .kernel_map import KernelMap, build_downsample_map, build_submanifold_map, kernel_offsets, lexicographic_order
from .norm import SparseBatchNorm, SparseReLU
from .tensor import SparseCache, SparseVoxels, cat_features

__all__ = [
    "KernelMap",
    "SparseBatchNorm",
    "SparseCache",
    "SparseConv3d",
    "SparseReLU",
    "SparseVoxels",
    "build_downsample_map",
    "build_submanifold_map",
    "cat_features",
    "conv3d",
    "kernel_offsets",
    "lexicographic_order",
    "sparse_conv_features",
]
