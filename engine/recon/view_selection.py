"""Which keyframes each tile is fused with.

Official inference (vortx-spec.md section 4): a tile takes up to N random keyframes among those that
see at least one of its coarse voxels, seed 0. Unlike the official code, a tile with no more than N
candidates takes only the keyframes that see it (the official code then takes *all* keyframes; views
that see none of the tile only add masked-out tokens and cost). Sampling is seeded per tile with
(seed, tile index), so a tile's views do not depend on how many other tiles there are.
"""

from __future__ import annotations

from typing import Optional

import numpy as np

from .bounds import SceneBounds
from .settings import COARSE_FACTOR
from .tiles import Tile, VoxelGrid


def views_seeing_points(points: np.ndarray, Ks: np.ndarray, poses: np.ndarray, sizes: np.ndarray, chunk: int = 64) -> np.ndarray:
    """(V,) bool: does view v see at least one of `points`?

    points: (M, 3) world; Ks: (V, 3, 3) pixels; poses: (V, 4, 4) camera-to-world; sizes: (V, 2)
    (width, height). "Sees" = projects to 0 <= u < W, 0 <= v < H with z > 0, as in training view
    selection. Views are processed `chunk` at a time to bound the (chunk, M, 3) projection buffer.
    """
    points = np.asarray(points, dtype=np.float64)
    seen = np.zeros(len(poses), dtype=bool)
    for a in range(0, len(poses), chunk):
        b = min(a + chunk, len(poses))
        world_to_cam = np.linalg.inv(poses[a:b])  # (c, 4, 4)
        cam = np.einsum("cij,mj->cmi", world_to_cam[:, :3, :3], points) + world_to_cam[:, None, :3, 3]
        z = cam[..., 2]
        in_front = z > 1e-6
        pix = np.einsum("cij,cmj->cmi", Ks[a:b], cam)
        safe_z = np.where(in_front, z, 1.0)
        u, v = pix[..., 0] / safe_z, pix[..., 1] / safe_z
        w, h = sizes[a:b, 0, None], sizes[a:b, 1, None]
        inside = in_front & (u >= 0) & (u < w) & (v >= 0) & (v < h)
        seen[a:b] = inside.any(axis=1)
    return seen


def tile_coarse_points(tile: Tile, grid: VoxelGrid, within: Optional[SceneBounds] = None) -> np.ndarray:
    """World positions (M, 3) of the tile's coarse voxels (corner convention), optionally only those
    inside the scene bounds (the ones the driver fuses)."""
    indices = grid.level_indices(tile, COARSE_FACTOR, within)
    return grid.origin + indices * (grid.voxel_size * COARSE_FACTOR)


def sample_views(candidates: np.ndarray, max_views: int, rng: np.random.Generator) -> np.ndarray:
    """Up to `max_views` of `candidates` (1-D int array), uniformly without replacement, sorted."""
    candidates = np.asarray(candidates, dtype=np.int64)
    if len(candidates) <= max_views:
        return np.sort(candidates)
    return np.sort(rng.choice(candidates, size=max_views, replace=False))


def select_views_for_tile(
    tile: Tile,
    grid: VoxelGrid,
    Ks: np.ndarray,
    poses: np.ndarray,
    sizes: np.ndarray,
    max_views: int,
    seed: int,
    within: Optional[SceneBounds] = None,
) -> np.ndarray:
    """Keyframe positions (<= max_views,) int64, sorted, that see the tile (its part inside `within`
    when given); empty when none does."""
    seen = views_seeing_points(tile_coarse_points(tile, grid, within), Ks, poses, sizes)
    rng = np.random.default_rng([seed, *tile.index])
    return sample_views(np.flatnonzero(seen), max_views, rng)
