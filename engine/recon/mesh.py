"""Fine sparse TSDF -> triangle mesh (marching cubes), as the official inference does (spec section 4).

TSDF sign (ground-truth convention, spec section 2): negative in front of the surface (free space,
the cameras' side), positive behind it. Marching cubes runs on -tsdf at level 0; with scikit-image's
default winding, triangles then face the *larger* values of its input, i.e. free space, so the face
and vertex normals point toward the cameras (tests/engine/recon/test_mesh.py checks this on a sphere).
Values live at voxel corners: a vertex at continuous grid index p lies at p * voxel_size + origin.
"""

from __future__ import annotations

from typing import Optional

import numpy as np
from skimage.measure import marching_cubes

from ..mesh_io import Mesh
from ..meshops import compact, vertex_normals
from .recon_result import empty_mesh


def dense_volume(indices: np.ndarray, values: np.ndarray, corner: Optional[np.ndarray] = None) -> tuple[np.ndarray, np.ndarray]:
    """Scatter sparse values into their bounding box (from `corner` (3,) when given), NaN where no voxel exists.

    indices: (N, 3) int fine-voxel indices; values: (N,). Returns the volume (X, Y, Z) float32 and the
    index (3,) int64 of its first voxel.
    """
    indices = np.asarray(indices, dtype=np.int64)
    offset = indices.min(axis=0) if corner is None else np.asarray(corner, dtype=np.int64)
    local = indices - offset
    volume = np.full(tuple(local.max(axis=0) + 1), np.nan, dtype=np.float32)
    volume[local[:, 0], local[:, 1], local[:, 2]] = values
    return volume, offset


def complete_cubes(valid: np.ndarray) -> np.ndarray:
    """(X, Y, Z) bool mask for scikit-image: True at (x, y, z) when all 8 corners of the cube
    spanning [x-1, x] x [y-1, y] x [z-1, z] are valid.

    scikit-image 0.24 tests its mask once per cube, at the cube's *last* corner (measured: a mask
    block [c-1, c+1]^3 yields vertices in [c-2, c+1]^3). Requiring all 8 corners keeps NaN out of the
    vertex interpolation instead of creating NaN vertices that must be cut away afterwards.
    """
    cubes = np.zeros_like(valid)
    X, Y, Z = valid.shape
    inner = np.ones((X - 1, Y - 1, Z - 1), dtype=bool)
    for dx in (0, 1):
        for dy in (0, 1):
            for dz in (0, 1):
                inner &= valid[dx:X - 1 + dx, dy:Y - 1 + dy, dz:Z - 1 + dz]
    cubes[1:, 1:, 1:] = inner
    return cubes


def extract_mesh(indices: np.ndarray, tsdf: np.ndarray, origin: np.ndarray, voxel_size: float,
                 corner: Optional[np.ndarray] = None) -> Mesh:
    """Mesh of the zero level of a sparse TSDF, in world metres; empty when there is no zero crossing.

    indices: (N, 3) int fine-voxel indices; tsdf: (N,) in [-1.05, 1.05]; origin: (3,) world position of
    index 0. Colours are left None (see colour.py). corner (3,): the first index of a block of a larger
    grid (indices >= corner); blocks that share a face then give bit-identical vertices on it, and no
    cube twice (a cube belongs to the block of its last corner, see `complete_cubes`).
    """
    if len(indices) == 0:
        return empty_mesh()
    volume, offset = dense_volume(indices, tsdf, corner)
    if min(volume.shape) < 2:
        return empty_mesh()
    valid = ~np.isnan(volume)
    mask = complete_cubes(valid)
    known = volume[valid]
    if not mask.any() or known.min() >= 0 or known.max() <= 0:
        return empty_mesh()
    # NaNs sit only in masked-out cubes; fill them so scikit-image's range check sees finite data.
    filled = np.where(valid, -volume, 1.0).astype(np.float32)
    try:
        # allow_degenerate=False: a grid value of exactly 0 would otherwise give zero-area triangles.
        verts, faces, _, _ = marching_cubes(filled, level=0.0, mask=mask, allow_degenerate=False)
    except (ValueError, RuntimeError):
        return empty_mesh()  # no surface inside the masked cubes
    faces = faces.astype(np.int64)
    finite = np.isfinite(verts).all(axis=1)
    faces = faces[finite[faces].all(axis=1)]
    if len(faces) == 0:
        return empty_mesh()
    verts, faces = compact(verts, faces)
    world = (verts.astype(np.float64) + offset) * voxel_size + np.asarray(origin, dtype=np.float64)
    vertices = world.astype(np.float32)
    faces32 = faces.astype(np.int32)
    return Mesh(vertices=vertices, faces=faces32, normals=vertex_normals(vertices, faces32), colors=None)
