"""Stereo depth maps fused into a TSDF with the project's own integration (engine/tsdf/integration.py).

Fusion is the stereo outlier filter: a wrong depth in one view is outvoted by the free space the
other views see through it (stereo-evidence.md: with many overlapping views this beats a strict
cross-view consistency check). The truncation defaults to 3 voxels, as in the ground truth and
FineRecon; the stereo method fuses with its own wider band (engine/recon/stereo_fusion.py).
"""

from __future__ import annotations

from typing import Optional, Sequence

import numpy as np
import torch

from ..jobs import CancelToken, ProgressCallback
from ..tsdf.integration import fuse_tsdf
from .depth_maps import DepthMap

TRUNCATION_VOXELS = 3.0  # the ground truth's and FineRecon's; the stereo method fuses with its own


def fuse_depth_maps(
    maps: Sequence[DepthMap],
    origin: np.ndarray,
    dims: Sequence[int],
    voxel_size: float,
    truncation_voxels: float = TRUNCATION_VOXELS,
    device: Optional[torch.device] = None,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
) -> tuple[np.ndarray, np.ndarray]:
    """(tsdf, weight), each (X, Y, Z) float32, of the depth maps on the grid origin + index * voxel_size.

    tsdf follows the ground-truth convention (negative in front of surfaces, +1 unobserved);
    weight counts the depth maps that updated a voxel.
    """
    if not maps:
        dims = tuple(int(d) for d in dims)
        return np.ones(dims, np.float32), np.zeros(dims, np.float32)
    tsdf, weight = fuse_tsdf([m.depth for m in maps], np.stack([m.K for m in maps]), np.stack([m.pose for m in maps]),
                             origin, dims, voxel_size, truncation_voxels * voxel_size, depth_cap=None, device=device,
                             progress=progress, cancel=cancel)
    return tsdf.cpu().numpy(), weight.cpu().numpy()
