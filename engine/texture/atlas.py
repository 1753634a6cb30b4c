"""A UV atlas for a result mesh with xatlas (the library Blender's and Godot's lightmappers build on).

xatlas cuts the surface into charts of low distortion, flattens each and packs them into one square;
vertices on a cut are split, so the atlas mesh has more vertices than its source and records which
source vertex each one copies.

Marching-cubes surfaces of real photos are rough at the voxel scale, and xatlas ends a chart where the
normals turn, so a room came out as ~13,000 charts of ~9 faces (120k-face demo room). The charts are
therefore cut on a smoothed copy of the surface (Taubin smoothing, which unlike plain Laplacian
smoothing does not shrink the surface, so a low-poly mesh keeps its shape; same vertices and faces):
1,900 charts for the demo room (100k faces), each a larger piece of wall. The UVs then belong to the
real vertices: a voxel-scale crumple gets fewer texels than its (noise) area, the smooth wall under it
its share.

xatlas's chart search grows faster than the face count (demo room: 14 s at 25k faces, 112 s at 100k),
so the surface is cut into BLOCK_SIZE cubes first, each given to xatlas as a mesh of its own; it
charts them separately and packs all charts into one atlas (100k faces: ~60 s -> 14 s). Block borders
become chart borders, which the bake levels like any other seam.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

from ..errors import VortxError
from ..jobs import CancelToken
from ..native_worker import run_in_child

SMOOTHING_ITERATIONS = 10  # Taubin steps; demo room at 100k faces: none 3,851 charts, 10 -> 1,923, 30 -> 1,681
TAUBIN = (0.5, -0.53)  # shrink then inflate by these factors each step (Taubin 1995's usual pair)
PADDING_MARGIN = 1.5  # xatlas's atlas overshoots the resolution by ~1.15-1.5x on rooms: pad that much more
BLOCK_SIZE = 1.0  # metres; 0.5 m was no faster (10.8 s vs 14.0 s at 100k faces) and made 15 % more charts
ATLAS_STEP = "texture atlas (xatlas)"
# Seconds: a fixed start plus per face. Far above what xatlas takes (demo room: 14 s at 100k faces,
# a limit of 320 s), so only a hang meets it, also on a slow or busy machine.
ATLAS_TIME_LIMIT_S = (120.0, 2e-3)
# xatlas's one observed crash did not repeat on the same input (see manifold_faces): a second fresh
# process gets past such a timing-dependent crash, a deterministic one fails again and is reported.
ATLAS_TRIES = 2
ATLAS_ADVICE = ("Try again; if it fails again, bake with another face budget (Face Budget, --face-budget) or "
                "texture size, which gives xatlas a different mesh.")


@dataclass
class Atlas:
    """source_vertex (V', ) int64: the input vertex each atlas vertex copies; faces (F, 3) int32 into the
    atlas vertices, in the input's face order; uvs (V', 2) float32 in [0, 1], v up (OBJ / Blender);
    charts: how many charts xatlas made; utilisation: the share of xatlas's atlas the charts cover;
    padding: the texels left between charts in the texture (asked-for padding, less any overshoot)."""

    source_vertex: np.ndarray
    faces: np.ndarray
    uvs: np.ndarray
    charts: int
    utilisation: float
    padding: float


def uv_atlas(vertices: np.ndarray, faces: np.ndarray, normals: np.ndarray | None, texture_size: int,
             padding: int, cancel: Optional[CancelToken] = None) -> Atlas:
    """Charts and packing for a `texture_size` square with `padding` texels between charts.

    vertices (V, 3); faces (F, 3); normals (V, 3) or None (unused: charts follow the smoothed surface).
    xatlas runs in a child process (native_worker.py): a crash or hang there raises NativeStepError
    and leaves this process, and Blender with it, running.
    """
    if len(faces) == 0:
        raise VortxError("the mesh has no faces, so there is nothing to texture")
    faces = np.asarray(faces, np.int64)
    # NaN positions become NaN UVs, on which xatlas's packing loops forever (xatlas issue #54).
    if not np.isfinite(np.asarray(vertices)[np.unique(faces)]).all():
        raise VortxError("the mesh has vertices at NaN or infinite positions, so no UV atlas can be made: "
                         "remove them (Blender: Mesh > Clean Up) or reconstruct again")
    smoothed = smooth_positions(np.asarray(vertices, np.float64), faces, SMOOTHING_ITERATIONS).astype(np.float32)
    blocks = face_blocks(np.asarray(vertices, np.float64), faces, BLOCK_SIZE)
    split_faces, split_source = manifold_faces(faces, len(vertices))
    layout = run_in_child(ATLAS_STEP, xatlas_layout,
                          {"positions": smoothed[split_source], "faces": split_faces, "block_faces": np.concatenate(blocks),
                           "block_ends": np.cumsum([len(block) for block in blocks])},
                          {"texture_size": int(texture_size), "padding": int(padding)},
                          time_limit_s=ATLAS_TIME_LIMIT_S[0] + ATLAS_TIME_LIMIT_S[1] * len(faces), cancel=cancel,
                          advice=ATLAS_ADVICE, tries=ATLAS_TRIES)
    if int(layout["charts"]) == 0:  # e.g. every face of zero area: nothing to lay out
        raise VortxError("no UV atlas could be made: the mesh's faces have no area (collapsed or degenerate mesh)")
    width, height = int(layout["width"]), int(layout["height"])
    scale = texture_size / max(width, height, texture_size)  # an atlas larger than the texture is shrunk into it
    source_vertex, atlas_faces = split_source[layout["source_vertex"]], layout["faces"]
    # xatlas normalises UVs by its own atlas size (width x height texels): back to atlas texels, then
    # into the texture with one factor for both axes, so every chart keeps its shape and density.
    uvs = layout["uvs"] * [width, height] * scale / texture_size
    if not np.array_equal(source_vertex[atlas_faces], faces):
        raise VortxError("the UV atlas changed the mesh's faces; the mesh may be degenerate")
    return Atlas(
        source_vertex=source_vertex,
        faces=atlas_faces.astype(np.int32),
        uvs=np.clip(uvs, 0.0, 1.0).astype(np.float32),
        charts=int(layout["charts"]),
        utilisation=float(layout["utilisation"]),
        padding=float(np.ceil(padding * PADDING_MARGIN) * scale),
    )


def smooth_positions(vertices: np.ndarray, faces: np.ndarray, iterations: int) -> np.ndarray:
    """(V, 3) float64 after `iterations` Taubin steps: move each vertex toward the mean of its edge
    neighbours by TAUBIN[0], then away by TAUBIN[1]; noise goes, the overall shape and size stay.
    Vertices on open borders do not move."""
    from scipy.sparse import coo_matrix, diags  # defers scipy: slow to import

    n = len(vertices)
    rows = np.concatenate([faces[:, 0], faces[:, 1], faces[:, 2], faces[:, 1], faces[:, 2], faces[:, 0]])
    cols = np.concatenate([faces[:, 1], faces[:, 2], faces[:, 0], faces[:, 0], faces[:, 1], faces[:, 2]])
    adjacency = coo_matrix((np.ones(len(rows)), (rows, cols)), shape=(n, n)).tocsr()
    adjacency.data[:] = 1.0  # an edge shared by two faces counts once
    degree = np.asarray(adjacency.sum(axis=1)).ravel()
    mean_of_neighbours = diags(1.0 / np.maximum(degree, 1.0)) @ adjacency
    # Vertices on an open border stay put: a lone wall or triangle would otherwise shrink to a point.
    edges = np.sort(np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]]), axis=1)
    unique_edges, uses = np.unique(edges, axis=0, return_counts=True)
    border = np.zeros(n, bool)
    border[unique_edges[uses == 1].ravel()] = True
    x = vertices.copy()
    moving = ((degree > 0) & ~border)[:, None]
    for _ in range(iterations):
        for factor in TAUBIN:
            x = np.where(moving, x + factor * (mean_of_neighbours @ x - x), x)
    return x


def xatlas_layout(positions: np.ndarray, faces: np.ndarray, block_faces: np.ndarray, block_ends: np.ndarray,
                  texture_size: int, padding: int) -> dict:
    """xatlas on the blocks (run in the child process: see uv_atlas). positions (V, 3) float32, the
    smoothed copy; faces (F, 3) int64; block_faces: the face ids of every block one after the other,
    block_ends: where each block ends in it. -> source_vertex (V', ), faces (F, 3) int64 into the atlas
    vertices in the input's face order, uvs (V', 2) normalised by xatlas's atlas, its width and height
    in texels, charts, utilisation (charts 0: xatlas laid out nothing).

    xatlas aims its texel density at the resolution but its atlas often comes out larger (demo room:
    2,364 x 2,344 for 2,048, more with many small charts), and a second packing at a density lowered by
    that factor came out far smaller (0.8 of the square) at twice the time. So it packs once, with the
    padding raised by PADDING_MARGIN to cover the usual overshoot; the caller scales the atlas into the
    square (one density, no squeeze) and reports the padding that is left.
    """
    import xatlas  # defers xatlas: optional native package

    blocks = np.split(block_faces, block_ends[:-1])
    atlas = xatlas.Atlas()
    block_vertices = []
    for block in blocks:
        used, local = np.unique(faces[block], return_inverse=True)
        block_vertices.append(used)
        atlas.add_mesh(positions[used], local.reshape(-1, 3).astype(np.uint32))
    pack = xatlas.PackOptions()
    pack.resolution = int(texture_size)
    pack.padding = int(np.ceil(padding * PADDING_MARGIN))
    pack.bilinear = True  # leave room for bilinear filtering at chart borders
    pack.blockAlign = True
    atlas.generate(xatlas.ChartOptions(), pack)
    if atlas.atlas_count < 1:
        return {"charts": 0}
    if atlas.atlas_count > 1:  # not asked for (resolution with automatic density packs into one)
        raise VortxError(f"the UV atlas needed {atlas.atlas_count} textures; use a larger texture size")
    source_parts, uv_parts = [], []
    atlas_faces = np.empty_like(faces)
    offset = 0
    for i, (block, used) in enumerate(zip(blocks, block_vertices)):
        mapping, block_atlas_faces, uvs = atlas[i]
        source_parts.append(used[mapping.astype(np.int64)])
        uv_parts.append(uvs)
        atlas_faces[block] = block_atlas_faces.astype(np.int64) + offset
        offset += len(mapping)
    return {"source_vertex": np.concatenate(source_parts), "faces": atlas_faces, "uvs": np.concatenate(uv_parts),
            "width": int(atlas.width), "height": int(atlas.height), "charts": int(atlas.chart_count),
            "utilisation": float(atlas.utilization)}


def manifold_faces(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """The faces with every edge in at most two faces, wound opposite ways, as xatlas's half-edge mesh
    needs. -> (faces (F, 3) int64 into the split vertices, source (V', ) int64: the input vertex each
    split vertex copies; the first vertex_count are the input's own).

    A face that would be the third on an edge, or the second with the same direction (a fold), gets
    three vertices of its own: it becomes a chart by itself, the rest keep their neighbours.
    Why: xatlas's charting walks a half-edge mesh, which its author says only works for manifold
    input (xatlas issue #3), and it does not check. The batch VR test's mesh, on which xatlas
    segfaulted once in ~15-20 runs, is the same in every run (seeded) and has 16 edges in 3-4 faces
    and 23 folded edges (29 of its 283 faces; edge collapses leave them). The crash did not come back
    in 1,400 xatlas runs on that exact input (alone, and beside bpy and busy torch threads), so it
    depends on xatlas's thread timing too; these faces are the part of the input that breaks xatlas's
    assumptions, so they no longer reach it (135 charts instead of 128 there). The cost is small: on 12
    random decimated marching-cubes blobs (250-1,900 faces, 0-356 faces cut apart) charts grew by 0-17 %
    and the atlas utilisation moved by at most 2.4 points.
    """
    count = len(faces)
    directed = np.concatenate([faces[:, [0, 1]], faces[:, [1, 2]], faces[:, [2, 0]]])
    face_of = np.tile(np.arange(count), 3)
    undirected = np.sort(directed, axis=1)
    order = np.lexsort((face_of, undirected[:, 1], undirected[:, 0]))  # by edge, then face order
    edges = undirected[order]
    starts = np.r_[True, (edges[1:] != edges[:-1]).any(axis=1)]
    first = np.maximum.accumulate(np.where(starts, np.arange(len(edges)), 0))  # each row's edge's first row
    rank = np.arange(len(edges)) - first  # 0: the edge's first face, 1: its second, ...
    forward = directed[order][:, 0] == edges[:, 0]
    # Conservative: one pass, so a face after a removed one may go too; every kept edge is manifold.
    conflict = (rank >= 2) | ((rank == 1) & (forward == forward[first]))
    apart = np.zeros(count, bool)
    apart[face_of[order][conflict]] = True
    faces = faces.copy()
    source = np.arange(vertex_count, dtype=np.int64)
    if apart.any():
        own = faces[apart]
        faces[apart] = vertex_count + np.arange(own.size).reshape(-1, 3)
        source = np.concatenate([source, own.reshape(-1)])
    return faces, source


def face_blocks(vertices: np.ndarray, faces: np.ndarray, size: float) -> list[np.ndarray]:
    """The faces (index arrays, ascending) whose centroids fall in each `size` cube that holds any."""
    centroids = vertices[faces].mean(axis=1)
    _, label = np.unique(np.floor(centroids / size).astype(np.int64), axis=0, return_inverse=True)
    label = label.reshape(-1)
    order = np.argsort(label, kind="stable")
    return np.split(order, np.flatnonzero(np.diff(label[order])) + 1)
