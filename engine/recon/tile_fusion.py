"""Back-project and fuse one tile's voxels with the tile's views, a chunk of voxels at a time.

The transformer attends over views per voxel, so its working memory is about
chunk x views x (a few x channels + heads x views) floats. Streaming fixed-size chunks through it
keeps that bound independent of tile size and scene size; only the fused (M, C) output is kept.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
import torch

from ..jobs import CancelToken, check
from .features import FeatureCache


@torch.inference_mode()
def fuse_tile(
    model: torch.nn.Module,
    level: int,
    points: torch.Tensor,
    cache: FeatureCache,
    views: np.ndarray,
    device: torch.device,
    chunk: int,
    cancel: Optional[CancelToken] = None,
) -> torch.Tensor:
    """Fused features (M, C_level) float32 on the CPU.

    points: (M, 3) float32 world positions (voxel corners) of the tile's voxels at this level;
    views: keyframe positions (v,) in the cache.
    """
    feats, K, poses = cache.views(level, views, device)
    outputs = []
    for start in range(0, len(points), chunk):
        check(cancel)
        block = points[start:start + chunk].to(device)
        fused = model.fuse(level, block, feats, K, poses, cache.image_hw, with_views=False)
        outputs.append(fused.features.to("cpu", torch.float32))
    if not outputs:
        return torch.zeros((0, feats.shape[1]), dtype=torch.float32)
    return torch.cat(outputs)
