"""The stereo method's fusion and meshing, block by block, so a space of any size fits in memory.

The fusion grid (`stereo_fusion.fusion_grid`) covers every surface the depth maps saw: a 32 m
corridor is a 800 x 500 x 100 grid at 4 cm. Rather than one dense grid, it is cut into horizontal
blocks of `BLOCK_VOXELS` x `BLOCK_VOXELS` voxels (full height) that share their border layer. Each
block is fused with the depth maps whose frusta reach it and meshed at once; only its triangles are
kept. A block's voxels get bit for bit the values the whole grid would give them (`fuse_tsdf`'s
`start`), and a cube belongs to the block of its last corner (`extract_mesh`'s `corner`), so the
blocks' meshes meet in identical vertices, welded into one mesh equal to the whole grid's
(tests/engine/recon/test_block_fusion.py). Memory is one block's, whatever the size of the space; the
time is the depth maps' frusta, as before.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
import torch

from ..geometry.cameras import frustum_corners
from ..jobs import CancelToken, ProgressCallback, check, report
from ..mesh_io import Mesh
from ..meshops import merge_duplicate_vertices_indexed, vertex_normals
from ..stereo.depth_maps import DepthMap
from ..stereo.fused_tsdf import fuse_depth_maps, fuse_stereo_evidence
from .mesh import extract_mesh
from .recon_result import empty_mesh

# A block's side in voxels: 6.4 m at 4 cm. A room of that size is one block; one block's fusion
# (its arrays and one depth map's working set over it) stays a few hundred MB at any room height.
BLOCK_VOXELS = 160
# Vertices on a shared block face are bit-identical (module doc); the weld only has to find equal
# positions, never to decide between near ones.
WELD_TOLERANCE_M = 1e-7
MIN_OBSERVATIONS = 1  # depth maps that must have updated a voxel before it can carry a surface


@dataclass(frozen=True)
class FusionBlock:
    start: np.ndarray  # (3,) int64 first voxel index in the fusion grid
    dims: tuple[int, int, int]  # voxels, the shared border layer included

    def box(self, origin: np.ndarray, voxel_size: float) -> tuple[np.ndarray, np.ndarray]:
        """World (min, max) of the block's voxel positions."""
        lo = origin + self.start * voxel_size
        return lo, lo + (np.array(self.dims) - 1) * voxel_size


@dataclass
class BlockMesh:
    """The welded mesh of every block, and per vertex the views that agree on a surface near it
    (evidence fusion only, else None)."""

    mesh: Mesh
    vertex_support: Optional[np.ndarray]  # (V,) float32
    blocks: int  # blocks fused (those some depth map reaches)
    block_dims: tuple[int, int, int]  # the largest block's voxels


def fusion_blocks(dims: Sequence[int], block_voxels: int = BLOCK_VOXELS) -> list[FusionBlock]:
    """Blocks covering a grid of `dims` (X, Y, Z) voxels: `block_voxels` cubes wide in x and y, the full
    height, neighbours sharing one layer of voxels (the cubes between two blocks need both)."""
    if block_voxels < 2:
        raise ValueError(f"a fusion block needs at least 2 voxels a side, got {block_voxels}")
    X, Y, Z = (int(d) for d in dims)
    blocks = []
    for x in range(0, max(X - 1, 1), block_voxels):
        for y in range(0, max(Y - 1, 1), block_voxels):
            size = (min(block_voxels + 1, X - x), min(block_voxels + 1, Y - y), Z)
            blocks.append(FusionBlock(np.array([x, y, 0], np.int64), size))
    return blocks


def frustum_box(depth_map: DepthMap, reach: float) -> tuple[np.ndarray, np.ndarray]:
    """World (min, max) of where a depth map can change the TSDF: its frustum to its deepest depth + reach."""
    height, width = depth_map.depth.shape
    deepest = float(depth_map.depth.max())
    corners = np.vstack([depth_map.pose[:3, 3], frustum_corners(depth_map.K, depth_map.pose, width, height, deepest + reach)])
    return corners.min(axis=0), corners.max(axis=0)


def fuse_blocks(
    maps: Sequence[DepthMap],
    origin: np.ndarray,
    dims: Sequence[int],
    voxel_size: float,
    truncation_voxels: float,
    device: torch.device,
    evidence_fusion: bool = False,
    min_support: int = 1,
    progress: Optional[ProgressCallback] = None,
    cancel: Optional[CancelToken] = None,
    block_voxels: int = BLOCK_VOXELS,
) -> BlockMesh:
    """Fuse `maps` on the grid origin + index * voxel_size of `dims` voxels block by block (module doc)
    and mesh it. evidence_fusion: weigh depths by their evidence and mesh only voxels `min_support`
    views agree on (`fused_tsdf.fuse_stereo_evidence`); else every observed voxel (`fuse_depth_maps`)."""
    origin = np.asarray(origin, np.float64)
    reach = (truncation_voxels + 2) * voxel_size
    with_depth = [m for m in maps if m.depth.size and m.depth.max() > 0]
    boxes = [frustum_box(m, reach) for m in with_depth]
    work = []
    blocks = fusion_blocks(dims, block_voxels)
    for block in blocks:
        lo, hi = block.box(origin, voxel_size)
        seen = [m for m, (a, b) in zip(with_depth, boxes) if np.all(a <= hi) and np.all(b >= lo)]
        if seen:
            work.append((block, seen))
    total = sum(len(seen) for _, seen in work)
    pieces: list[Mesh] = []
    supports: list[np.ndarray] = []
    done = 0
    for block, seen in work:
        check(cancel)

        def block_progress(stage: str, fused: int, _total: int, before: int = done) -> None:
            report(progress, stage, before + fused, total)

        if evidence_fusion:  # on the whole grid's lattice, from the block's first voxel
            fused = fuse_stereo_evidence(seen, origin, block.dims, voxel_size, truncation_voxels, device,
                                         block_progress, cancel, start=block.start)
            tsdf, keep, support = fused.tsdf, fused.surface_voxels(min_support), fused.support
        else:
            tsdf, weight = fuse_depth_maps(seen, origin, block.dims, voxel_size, truncation_voxels, device,
                                           block_progress, cancel, start=block.start)
            keep, support = weight >= MIN_OBSERVATIONS, None
        done += len(seen)
        local = np.argwhere(keep)
        # One block is the whole grid: meshed as the learned method meshes it, so the two agree bit for bit.
        corner = block.start if len(blocks) > 1 else None
        piece = extract_mesh(local + block.start, tsdf[keep], origin, voxel_size, corner=corner)
        del tsdf, keep
        if len(piece.faces) == 0:
            continue
        pieces.append(piece)
        if support is not None:
            index = np.round((piece.vertices - origin) / voxel_size).astype(np.int64) - block.start
            index = np.clip(index, 0, np.array(support.shape) - 1)
            supports.append(support[index[:, 0], index[:, 1], index[:, 2]])
    block_dims = tuple(int(d) for d in np.max([b.dims for b, _ in work], axis=0)) if work else (0, 0, 0)
    if not pieces:
        return BlockMesh(empty_mesh(), np.zeros(0, np.float32) if evidence_fusion else None, len(work), block_dims)  # type: ignore[arg-type]
    if len(pieces) == 1:  # nothing to weld
        vertex_support = supports[0] if supports else None
        return BlockMesh(pieces[0], vertex_support, len(work), block_dims)  # type: ignore[arg-type]
    offsets = np.cumsum([0] + [len(p.vertices) for p in pieces[:-1]])
    vertices = np.concatenate([p.vertices for p in pieces]).astype(np.float64)
    faces = np.concatenate([p.faces.astype(np.int64) + o for p, o in zip(pieces, offsets)])
    vertices, faces, first = merge_duplicate_vertices_indexed(vertices, faces, WELD_TOLERANCE_M)
    vertices32, faces32 = vertices.astype(np.float32), faces.astype(np.int32)
    mesh = Mesh(vertices=vertices32, faces=faces32, normals=vertex_normals(vertices32, faces32), colors=None)
    vertex_support = np.concatenate(supports)[first] if supports else None
    return BlockMesh(mesh, vertex_support, len(work), block_dims)  # type: ignore[arg-type]
