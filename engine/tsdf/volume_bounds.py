"""Volume bounds for ground-truth fusion: the union of the camera frusta (NeuralRecon/VoRTX rule).

Each frustum is the camera centre plus the four image corners pushed to that frame's largest valid
depth; up to 200 evenly spaced frames are used and the bounds start out containing the world
origin (vortx-spec.md section 2, `tools/generate_gt.py`).
"""

from __future__ import annotations

from typing import Sequence

import numpy as np

from ..geometry.cameras import frustum_corners


def frustum_bounds(
    depths: Sequence[np.ndarray],
    K: np.ndarray,
    cam_to_world: np.ndarray,
    depth_cap: float = 3.0,
    max_frames: int = 200,
    include_origin: bool = True,
) -> tuple[np.ndarray, np.ndarray]:
    """World AABB (min (3,), max (3,)) of the frusta of up to `max_frames` evenly spaced frames.

    depths: N maps (H, W) in metres (0 = invalid; values above `depth_cap` count as invalid, as they
    are dropped before fusion). K (3, 3) or (N, 3, 3); cam_to_world (N, 4, 4).
    """
    n = len(depths)
    if n == 0:
        raise ValueError("frustum_bounds needs at least one frame")
    Ks = np.broadcast_to(np.asarray(K, np.float64), (n, 3, 3)) if np.ndim(K) == 2 else np.asarray(K, np.float64)
    poses = np.asarray(cam_to_world, np.float64)
    picks = np.linspace(0, n - 1, max_frames).astype(np.int64) if n > max_frames else np.arange(n)
    lo = np.zeros(3) if include_origin else np.full(3, np.inf)
    hi = np.zeros(3) if include_origin else np.full(3, -np.inf)
    for i in picks:
        d = np.asarray(depths[i], np.float64)
        valid = np.isfinite(d) & (d > 0) & (d <= depth_cap)
        if not np.isfinite(poses[i]).all():
            continue
        max_depth = float(d[valid].max()) if valid.any() else 0.0
        pts = np.vstack([poses[i][:3, 3], frustum_corners(Ks[i], poses[i], d.shape[1], d.shape[0], max_depth)])
        lo = np.minimum(lo, pts.min(axis=0))
        hi = np.maximum(hi, pts.max(axis=0))
    return lo, hi


def volume_from_bounds(lo: np.ndarray, hi: np.ndarray, voxel_size: float) -> tuple[np.ndarray, tuple[int, int, int]]:
    """(origin (3,), dims) of the grid covering [lo, hi]: origin = lo, dims = round(extent / voxel_size).

    `round`, not `ceil`, matches the reference TSDFVolume, so our grids line up with its grids.
    """
    dims = np.maximum(np.round((np.asarray(hi) - np.asarray(lo)) / voxel_size), 1).astype(np.int64)
    return np.asarray(lo, np.float64).copy(), (int(dims[0]), int(dims[1]), int(dims[2]))
