"""The voxel-grid convention, stated once: a voxel's world position is its CORNER.

`position = index * voxel_size + origin` (no +0.5), as in the official VoRTX back-projection and
ground-truth fusion (vortx-spec.md section 1). TSDF fusion, trimming, occupancy targets and
marching cubes (vertex = index * voxel_size + origin) all use these two functions, so a grid sample
and a world point agree everywhere.
"""

from __future__ import annotations

from typing import Sequence, Union

import numpy as np
import torch

ArrayLike = Union[np.ndarray, Sequence[float]]


def axis_positions(
    origin: ArrayLike, start: int, count: int, voxel_size: float, axis: int,
    device: Union[str, torch.device, None] = None, dtype: torch.dtype = torch.float64,
) -> torch.Tensor:
    """World coordinates (count,) along one axis of voxel indices start .. start + count - 1."""
    o = float(np.asarray(origin, dtype=np.float64)[axis])
    return (torch.arange(int(start), int(start) + int(count), dtype=torch.float64) * voxel_size + o).to(device, dtype)


def voxel_positions(
    origin: ArrayLike,
    dims: Sequence[int],
    voxel_size: float,
    start: Sequence[int] = (0, 0, 0),
    device: Union[str, torch.device, None] = None,
    dtype: torch.dtype = torch.float32,
) -> torch.Tensor:
    """World positions of a block of voxels: (X, Y, Z, 3) for indices start + [0, dims)."""
    axes = [axis_positions(origin, start[a], dims[a], voxel_size, a, dtype=dtype) for a in range(3)]
    gx, gy, gz = torch.meshgrid(*axes, indexing="ij")
    return torch.stack([gx, gy, gz], dim=-1).to(device)


def world_to_voxel(points: np.ndarray, origin: ArrayLike, voxel_size: float) -> np.ndarray:
    """Nearest voxel index (N, 3) int64 of world points (N, 3): the voxel whose corner sample is closest."""
    return np.round((np.asarray(points, np.float64) - np.asarray(origin, np.float64)) / voxel_size).astype(np.int64)
