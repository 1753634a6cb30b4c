"""Trimming a mesh's points to the space the cameras observed.

Atlas trims the PREDICTION by rendering its depth in every ground-truth view (pyrender), zeroing it
where the ground-truth render is empty, re-fusing those depths and running marching cubes again. We
have no offscreen GL renderer in the engine, so we use the closest faithful substitute: keep the points
whose nearest voxel of the ground-truth TSDF was observed (weight > 0). Both keep surfaces in front of
or within the truncation band behind what the cameras saw and drop geometry beyond it; the render
route additionally removes predicted surfaces hidden behind other predicted surfaces in every view,
which this voxel test keeps when they lie in observed space.
"""

from __future__ import annotations

import numpy as np

from ..tsdf.grid import world_to_voxel
from ..tsdf.volume import TsdfVolume


def observed_mask(points: np.ndarray, volume: TsdfVolume) -> np.ndarray:
    """(N,) bool: the nearest voxel sample of each point (N, 3) lies in the volume and was observed."""
    idx = world_to_voxel(points, volume.origin, volume.voxel_size)
    dims = np.array(volume.dims)
    inside = np.all((idx >= 0) & (idx < dims), axis=1)
    keep = np.zeros(len(points), bool)
    i = idx[inside]
    keep[inside] = volume.weight[i[:, 0], i[:, 1], i[:, 2]] > 0
    return keep
