"""Sparse 3D U-Net: the voxel branch of torchsparse's SPVCNN as VoRTX uses it (vortx-spec.md section 1).

Channels ``cs = base * [1, 2, 4, 3, 3]``; with N input voxels at stride s:

    stem    conv3 (in -> cs0), BN, ReLU                                   N voxels, stride s
    stage1  conv k2 s2 (cs0), BN, ReLU; Res(cs0 -> cs1); Res(cs1)         stride 2s
    stage2  conv k2 s2 (cs1), BN, ReLU; Res(cs1 -> cs2); Res(cs2)         stride 4s
    up1     deconv k2 s2 (cs2 -> cs3), BN, ReLU; cat[up, stage1]; Res(cs3 + cs1 -> cs3); Res(cs3)
    up2     deconv k2 s2 (cs3 -> cs4), BN, ReLU; cat[up, stem];   Res(cs4 + cs0 -> cs4); Res(cs4)

Output: (N, cs4) features at exactly the input coordinates (same rows, same order). Internally the
network runs on (batch, x, y, z)-sorted rows, so its kernel maps live on a private cache, not on the
input's.

Attribute names and Sequential indices reproduce the official checkpoint keys under
``vortx.cnns3d.<level>.`` (e.g. ``stem.0.kernel`` [27, 137, 16], ``stage1.0.net.0.kernel`` [8, 16, 16],
``stage1.1.downsample.0.kernel`` [16, 32], ``up1.1.0.net.0.kernel`` [27, 80, 48]), so converting the
official weights is a prefix rename and a copy.
"""

from __future__ import annotations

import torch
from torch import nn

from ..sparse import SparseBatchNorm, SparseConv3d, SparseReLU, SparseVoxels, cat_features, lexicographic_order


class ConvBlock(nn.Module):
    """``net`` = conv (optionally transposed), BN, ReLU: SPVCNN's Basic(De)ConvolutionBlock."""

    def __init__(self, in_channels: int, out_channels: int, kernel_size: int, stride: int, transposed: bool = False):
        super().__init__()
        self.net = nn.Sequential(
            SparseConv3d(in_channels, out_channels, kernel_size, stride=stride, transposed=transposed),
            SparseBatchNorm(out_channels),
            SparseReLU(inplace=True),
        )

    def forward(self, x: SparseVoxels) -> SparseVoxels:
        return self.net(x)


class ResidualBlock(nn.Module):
    """ReLU(conv3, BN, ReLU, conv3, BN  +  skip); skip = identity, or 1x1 conv + BN when widths differ."""

    def __init__(self, in_channels: int, out_channels: int):
        super().__init__()
        self.net = nn.Sequential(
            SparseConv3d(in_channels, out_channels, 3),
            SparseBatchNorm(out_channels),
            SparseReLU(inplace=True),
            SparseConv3d(out_channels, out_channels, 3),
            SparseBatchNorm(out_channels),
        )
        # nn.Identity has no parameters, so identity skips add no checkpoint keys (as in SPVCNN).
        self.downsample: nn.Module
        if in_channels == out_channels:
            self.downsample = nn.Identity()
        else:
            self.downsample = nn.Sequential(SparseConv3d(in_channels, out_channels, 1), SparseBatchNorm(out_channels))
        self.relu = SparseReLU(inplace=True)

    def forward(self, x: SparseVoxels) -> SparseVoxels:
        return self.relu(self.net(x) + self.downsample(x))


class SparseUNet(nn.Module):
    """SPVCNN voxel branch. ``forward(x (N, in_channels)) -> (N, 3 * base_width)`` at x's coordinates."""

    def __init__(self, in_channels: int, base_width: int):
        super().__init__()
        cs = [base_width * m for m in (1, 2, 4, 3, 3)]
        self.in_channels = in_channels
        self.channels = tuple(cs)
        self.out_channels = cs[4]
        self.stem = nn.Sequential(SparseConv3d(in_channels, cs[0], 3), SparseBatchNorm(cs[0]), SparseReLU(inplace=True))
        self.stage1 = nn.Sequential(ConvBlock(cs[0], cs[0], 2, 2), ResidualBlock(cs[0], cs[1]), ResidualBlock(cs[1], cs[1]))
        self.stage2 = nn.Sequential(ConvBlock(cs[1], cs[1], 2, 2), ResidualBlock(cs[1], cs[2]), ResidualBlock(cs[2], cs[2]))
        self.up1 = nn.ModuleList(
            [
                ConvBlock(cs[2], cs[3], 2, 2, transposed=True),
                nn.Sequential(ResidualBlock(cs[3] + cs[1], cs[3]), ResidualBlock(cs[3], cs[3])),
            ]
        )
        self.up2 = nn.ModuleList(
            [
                ConvBlock(cs[3], cs[4], 2, 2, transposed=True),
                nn.Sequential(ResidualBlock(cs[4] + cs[0], cs[4]), ResidualBlock(cs[4], cs[4])),
            ]
        )

    def forward(self, x: SparseVoxels) -> SparseVoxels:
        if x.num_channels != self.in_channels:
            raise ValueError(f"SparseUNet expects {self.in_channels} input channels, got {x.num_channels}")
        order = lexicographic_order(x.coords)
        if order is None:
            return self._forward_sorted(x)
        # Run on (batch, x, y, z)-sorted rows, which makes every kernel map and convolution
        # cache-friendly (~1.5x faster), then put the rows back in the caller's order.
        inner = SparseVoxels(x.coords[order], x.feats[order], x.stride)
        inverse = torch.empty_like(order)
        inverse[order] = torch.arange(len(order), device=order.device)
        return x.replace_feats(self._forward_sorted(inner).feats[inverse])

    def _forward_sorted(self, x: SparseVoxels) -> SparseVoxels:
        x0 = self.stem(x)
        x1 = self.stage1(x0)
        x2 = self.stage2(x1)
        # Concatenation order [upsampled, skip] fixes the input-channel layout of the official weights.
        y3 = self.up1[1](cat_features([self.up1[0](x2), x1]))
        return self.up2[1](cat_features([self.up2[0](y3), x0]))
