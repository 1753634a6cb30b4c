"""A UV atlas for a result mesh with xatlas (the library Blender's and Godot's lightmappers build on).

xatlas cuts the surface into charts of low distortion, flattens each and packs them into one square;
vertices on a cut are split, so the atlas mesh has more vertices than its source and records which
source vertex each one copies.

Marching-cubes surfaces of real photos are rough at the voxel scale, and xatlas ends a chart where the
normals turn, so a room came out as ~13,000 charts of ~9 faces (120k-face demo room). The charts are
therefore cut on a smoothed copy of the surface (SMOOTHING_ITERATIONS of Laplacian smoothing, the same
vertices and faces): 4,350 charts for the demo room, each a larger piece of wall. The UVs then belong
to the real vertices; the stretch this adds is that of voxel-scale bumps, a few percent.

xatlas's chart search grows faster than the face count (demo room: 14 s at 25k faces, 112 s at 100k),
so the surface is cut into BLOCK_SIZE cubes first, each given to xatlas as a mesh of its own; it
charts them separately and packs all charts into one atlas (100k faces: ~60 s -> 14 s). Block borders
become chart borders, which the bake levels like any other seam.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from ..errors import VortxError

SMOOTHING_ITERATIONS = 10  # measured on the demo room: 10 -> 4,350 charts, 30 -> 4,172 (no better)
BLOCK_SIZE = 1.0  # metres; 0.5 m was no faster (10.8 s vs 14.0 s at 100k faces) and made 15 % more charts


@dataclass
class Atlas:
    """source_vertex (V', ) int64: the input vertex each atlas vertex copies; faces (F, 3) int32 into the
    atlas vertices, in the input's face order; uvs (V', 2) float32 in [0, 1], v up (OBJ / Blender);
    charts: how many charts xatlas made; utilisation: the share of the square the charts cover."""

    source_vertex: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    charts: int
    utilisation: float


def uv_atlas(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None, texture_size: int,
             padding: int) -> Atlas:
    """Charts and packing for a `texture_size` square with `padding` texels between charts.

    vertices (V, 3); faces (F, 3); normals (V, 3) or None (unused: charts follow the smoothed surface).
    """
    import xatlas

    if len(faces) == 0:
        raise VortxError("the mesh has no faces, so there is nothing to texture")
    atlas = xatlas.Atlas()
    faces = np.asarray(faces, np.int64)
    smoothed = smooth_positions(np.asarray(vertices, np.float64), faces, SMOOTHING_ITERATIONS).astype(np.float32)
    blocks = face_blocks(np.asarray(vertices, np.float64), faces, BLOCK_SIZE)
    block_vertices = []
    for block in blocks:
        used, local = np.unique(faces[block], return_inverse=True)
        block_vertices.append(used)
        atlas.add_mesh(smoothed[used], local.reshape(-1, 3).astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = int(texture_size)
    pack.padding = int(padding)
    pack.bilinear = True  # leave room for bilinear filtering at chart borders
    pack.blockAlign = True
    atlas.generate(xatlas.ChartOptions(), pack)
    source_parts, uv_parts = [], []
    atlas_faces = np.empty_like(faces)
    offset = 0
    for i, (block, used) in enumerate(zip(blocks, block_vertices)):
        mapping, block_faces, uvs = atlas[i]
        source_parts.append(used[mapping.astype(np.int64)])
        uv_parts.append(uvs)
        atlas_faces[block] = block_faces.astype(np.int64) + offset
        offset += len(mapping)
    source_vertex = np.concatenate(source_parts)
    uvs = np.concatenate(uv_parts)
    if not np.array_equal(source_vertex[atlas_faces], faces):
        raise VortxError("the UV atlas changed the mesh's faces; the mesh may be degenerate")
    return Atlas(
        source_vertex=source_vertex,
        faces=atlas_faces.astype(np.int32),
        uvs=np.clip(uvs, 0.0, 1.0).astype(np.float32),
        charts=int(atlas.chart_count),
        utilisation=float(atlas.utilization),
    )


def smooth_positions(vertices: np.ndarray, faces: np.ndarray, iterations: int) -> np.ndarray:
    """(V, 3) float64: each step moves every vertex half-way to the mean of its edge neighbours."""
    from scipy.sparse import coo_matrix, diags

    n = len(vertices)
    rows = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2], faces[:, 1], faces[:, 2], faces[:, 0]])
    cols = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0], faces[:, 0], faces[:, 1], faces[:, 2]])
    adjacency = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0  # an edge shared by two faces counts once
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    mean_of_neighbours = diags(1.0 / np.maximum(degree, 1.0)) @ adjacency
    x = vertices.copy()
    isolated = degree == 0
    for _ in range(iterations):
        x = np.where(isolated[:, None], x, 0.5 * x + 0.5 * (mean_of_neighbours @ x))
    return x


def face_blocks(vertices: np.ndarray, faces: np.ndarray, size: float) -> list[np.ndarray]:
    """The faces (index arrays, ascending) whose centroids fall in each `size` cube that holds any."""
    centroids = vertices[faces].mean(axis=1)
    _, label = np.unique(np.floor(centroids / size).astype(np.int64), axis=0, return_inverse=True)
    label = label.reshape(-1)
    order = np.argsort(label, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(label[order])) + 1)
