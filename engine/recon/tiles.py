"""The voxel grid and its tiles: non-overlapping blocks that fusion streams through one at a time.

A tile is (tile_size, tile_size, tile_height) fine voxels, default 96 x 96 x 48 = 3.84 x 3.84 x 1.92 m,
the training crop (vortx-spec.md section 4). The grid origin sits on a multiple of the coarse voxel
size and tile dimensions are multiples of 4 fine voxels, so every coarse voxel falls in exactly one
tile at every level. Voxel positions use the corner convention of the model: index * size + origin.

This module is numpy-only: the Blender tile overlay imports it (via `tile_grid`) without torch.
"""

from __future__ import annotations

import enum
from dataclasses import dataclass, field
from typing import Optional

import numpy as np

from ..geometry.view_selection import select_views
from .scene_bounds import SceneBounds
from .settings import COARSE_FACTOR


class TileState(str, enum.Enum):
    PENDING = "pending"  # not fused yet at the current level
    RUNNING = "running"  # being fused now
    DONE = "done"  # fused at every level and holds surface voxels
    EMPTY = "empty"  # no keyframe sees it, or every voxel in it was pruned


@dataclass
class Tile:
    index: tuple[int, int, int]  # position in the tile grid (i, j, k)
    start: np.ndarray  # (3,) int64 first fine-voxel index (inclusive)
    shape: np.ndarray  # (3,) int64 size in fine voxels
    minimum: np.ndarray  # (3,) world metres
    maximum: np.ndarray  # (3,) world metres
    state: TileState = TileState.PENDING
    views: np.ndarray = field(default_factory=lambda: np.zeros(0, dtype=np.int64))  # keyframe positions
    voxels: dict[str, int] = field(default_factory=dict)  # level label -> voxels fused in this tile

    def to_dict(self) -> dict:
        return {
            "index": list(self.index),
            "min": [float(v) for v in self.minimum],
            "max": [float(v) for v in self.maximum],
            "state": self.state.value,
            "views": [int(v) for v in self.views],
            "voxels": dict(self.voxels),
        }


@dataclass(frozen=True)
class VoxelGrid:
    origin: np.ndarray  # (3,) world position of fine voxel index 0 (its corner)
    voxel_size: float  # fine voxel size in metres
    tile_shape: np.ndarray  # (3,) int64 fine voxels per tile
    tiles_per_axis: np.ndarray  # (3,) int64

    @property
    def shape(self) -> np.ndarray:
        """(3,) fine voxels covered by all tiles."""
        return self.tile_shape * self.tiles_per_axis

    @property
    def num_tiles(self) -> int:
        return int(np.prod(self.tiles_per_axis))

    def tile_ids(self, indices: np.ndarray, scale: int) -> np.ndarray:
        """Flat tile id (N,) of voxels `indices` (N, 3) at a level `scale` times coarser than fine.

        Ids follow `make_tiles`' order (x slowest, z fastest).
        """
        tile = (np.asarray(indices, dtype=np.int64) * scale) // self.tile_shape
        ny, nz = int(self.tiles_per_axis[1]), int(self.tiles_per_axis[2])
        return (tile[:, 0] * ny + tile[:, 1]) * nz + tile[:, 2]

    def level_indices(self, tile: Tile, scale: int, within: SceneBounds | None = None) -> np.ndarray:
        """Every voxel index (M, 3) of `tile` at a level `scale` times coarser, x slowest; with
        `within`, only voxels whose cell [i, i + 1) * size overlaps those bounds."""
        lo = tile.start // scale
        hi = (tile.start + tile.shape) // scale
        if within is not None:
            size = self.voxel_size * scale
            lo = np.maximum(lo, np.floor((within.minimum - self.origin) / size + 1e-9).astype(np.int64))
            hi = np.minimum(hi, np.ceil((within.maximum - self.origin) / size - 1e-9).astype(np.int64))
        axes = [np.arange(a, max(a, b), dtype=np.int64) for a, b in zip(lo, hi)]
        return np.stack(np.meshgrid(*axes, indexing="ij"), axis=-1).reshape(-1, 3)


def make_tiles(bounds: SceneBounds, voxel_size: float, tile_size: int, tile_height: int) -> tuple[VoxelGrid, list[Tile]]:
    """Cover `bounds` with non-overlapping tiles aligned to the coarse grid."""
    tile_shape = np.array([tile_size, tile_size, tile_height], dtype=np.int64)
    if np.any(tile_shape % COARSE_FACTOR):
        raise ValueError(f"tile dimensions {tile_shape.tolist()} must be multiples of {COARSE_FACTOR}")
    coarse = voxel_size * COARSE_FACTOR
    origin = np.floor(bounds.minimum / coarse) * coarse
    tile_metres = tile_shape * voxel_size
    # A small epsilon stops float noise from adding a whole row of tiles for a box that fits exactly.
    counts = np.maximum(np.ceil((bounds.maximum - origin) / tile_metres - 1e-9), 1).astype(np.int64)
    grid = VoxelGrid(origin, float(voxel_size), tile_shape, counts)
    tiles = []
    for i in range(counts[0]):
        for j in range(counts[1]):
            for k in range(counts[2]):
                start = np.array([i, j, k], dtype=np.int64) * tile_shape
                lo = origin + start * voxel_size
                tiles.append(Tile((i, j, k), start, tile_shape.copy(), lo, lo + tile_metres))
    return grid, tiles


# Box corner c sits at (bit0(c) ? max : min, bit1(c) ? max : min, bit2(c) ? max : min).
BOX_EDGES = np.array(
    [[0, 1], [2, 3], [4, 5], [6, 7], [0, 2], [1, 3], [4, 6], [5, 7], [0, 4], [1, 5], [2, 6], [3, 7]], dtype=np.int32
)


def tile_coarse_points(tile: Tile, grid: VoxelGrid, within: Optional[SceneBounds] = None) -> np.ndarray:
    """World positions (M, 3) of the tile's coarse voxels (corner convention), optionally only those
    inside the scene bounds (the ones the driver fuses)."""
    indices = grid.level_indices(tile, COARSE_FACTOR, within)
    return grid.origin + indices * (grid.voxel_size * COARSE_FACTOR)


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
    """Keyframe positions (<= max_views,) int64, sorted, that see the tile's coarse voxels (its part
    inside `within` when given); empty when none does. Ks, poses, sizes are the keyframes'.

    The rule is training's (engine.geometry.view_selection.select_views). Sampling is seeded per tile
    with (seed, tile index), so a tile's views do not depend on how many other tiles there are.
    """
    rng = np.random.default_rng([seed, *tile.index])
    return select_views(tile_coarse_points(tile, grid, within), Ks, poses, sizes, np.arange(len(poses)), max_views, rng)


def tile_grid(tiles: list[Tile]) -> tuple[np.ndarray, np.ndarray, list[str]]:
    """Plain numpy data to draw the tiles: corners (T, 8, 3) float64 world metres, edges (12, 2) into
    the 8 corners of each box (`BOX_EDGES`) and each tile's state string."""
    corners = np.zeros((len(tiles), 8, 3), dtype=np.float64)
    for t, tile in enumerate(tiles):
        for c in range(8):
            bits = np.array([c & 1, (c >> 1) & 1, (c >> 2) & 1], dtype=bool)
            corners[t, c] = np.where(bits, tile.maximum, tile.minimum)
    return corners, BOX_EDGES.copy(), [tile.state.value for tile in tiles]
