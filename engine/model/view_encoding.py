"""View-direction encoding: tells each 2D feature which way its pixel looks in the world.

Per feature pixel, the world-space ray direction d (unit, 3 values) is encoded as
[d, sin(pi d), cos(pi d), sin(2 pi d), cos(2 pi d), ..., cos(2^(L-1) pi d)] (3 + 6L = 27 channels
for L = 4, in that order) and mixed into the features with a bias-free 1x1 conv (C + 27 -> C), as
the official `ViewDirectionEncoder`. Rays use the intrinsics scaled to the feature map by 1/stride
without a half-pixel correction, i.e. feature pixel (u, v) is image pixel (stride u, stride v).
"""

from __future__ import annotations

import math

import torch
from torch import nn

from ..geometry.cameras import intrinsics_at_stride

NUM_FREQUENCIES = 4
ENCODING_CHANNELS = 3 + 6 * NUM_FREQUENCIES  # 27


def ray_directions(K: torch.Tensor, cam_to_world: torch.Tensor, height: int, width: int) -> torch.Tensor:
    """Unit world-space ray through every pixel centre (u, v) = integer pixel indices.

    K: (V, 3, 3) intrinsics of this map; cam_to_world: (V, 4, 4), OpenCV camera axes.
    Returns (V, 3, height, width).
    """
    dtype, device = K.dtype, K.device
    v, u = torch.meshgrid(
        torch.arange(height, dtype=dtype, device=device),
        torch.arange(width, dtype=dtype, device=device),
        indexing="ij",
    )
    fx, fy = K[:, 0, 0, None, None], K[:, 1, 1, None, None]
    cx, cy = K[:, 0, 2, None, None], K[:, 1, 2, None, None]
    x = (u - cx) / fx
    y = (v - cy) / fy
    rays_cam = torch.stack([x, y, torch.ones_like(x)], dim=1)  # (V, 3, h, w)
    rotation = cam_to_world[:, :3, :3].to(dtype)
    rays_world = torch.einsum("vij,vjhw->vihw", rotation, rays_cam)
    return rays_world / torch.linalg.norm(rays_world, dim=1, keepdim=True)


def encode_directions(directions: torch.Tensor, num_frequencies: int = NUM_FREQUENCIES) -> torch.Tensor:
    """(V, 3, h, w) unit directions -> (V, 3 + 6 L, h, w) Fourier encoding [d, sin, cos per frequency]."""
    parts = [directions]
    for i in range(num_frequencies):
        angle = directions * (math.pi * 2**i)
        parts += [torch.sin(angle), torch.cos(angle)]
    return torch.cat(parts, dim=1)


class ViewDirectionEncoder(nn.Module):
    """(features, ray encoding) -> features of the same width. Parameter key: `conv.0.weight`."""

    def __init__(self, channels: int) -> None:
        super().__init__()
        conv = nn.Conv2d(channels + ENCODING_CHANNELS, channels, 1, bias=False)
        nn.init.xavier_normal_(conv.weight)
        self.conv = nn.Sequential(conv)

    def forward(self, feats: torch.Tensor, K: torch.Tensor, cam_to_world: torch.Tensor, stride: int) -> torch.Tensor:
        """feats (V, C, h, w); K (V, 3, 3) in image pixels; cam_to_world (V, 4, 4) -> (V, C, h, w)."""
        h, w = feats.shape[-2:]
        rays = ray_directions(intrinsics_at_stride(K.to(feats.dtype), stride), cam_to_world, h, w)
        return self.conv(torch.cat([feats, encode_directions(rays)], dim=1))
