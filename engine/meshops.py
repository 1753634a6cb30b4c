"""Mesh helpers on plain arrays: vertex normals, dropping unused vertices (`compact`), connected
pieces, dropping the small ones, merging duplicate vertices. Used by the reconstruction (marching
cubes), the texture bake and its VR mesh alike.

A reconstruction's mesh often carries small floating pieces (a few triangles of noise in free space,
a fragment seen by one photo). In VR those read as dust in the air and cost draw calls, so the user
can drop every piece below a size. Everything here is numpy (+ scipy's graph components, which
scikit-image already depends on) and works on `engine.mesh_io.Mesh`, so the CLI, the batch export
and Blender share it. Decimation is not here: Blender's Decimate modifier does it inside Blender
(vortx_blender.result), keeping colour attributes.

Pieces are vertex-connected: two triangles belong to the same piece when they share a vertex.
Marching cubes emits shared vertices, so this is the mesh's real connectivity.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np

from .mesh_io import Mesh


def vertex_normals(vertices: np.ndarray, faces: np.ndarray) -> np.ndarray:
    """Area-weighted unit vertex normals (V, 3) float32, following the faces' winding."""
    v = vertices.astype(np.float64)
    face_normals = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])  # length = 2 * area
    normals = np.zeros_like(v)
    for corner in range(3):
        np.add.at(normals, faces[:, corner], face_normals)
    length = np.linalg.norm(normals, axis=1, keepdims=True)
    return (normals / np.where(length > 0, length, 1.0)).astype(np.float32)


def compact(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Drop vertices that no face uses and renumber the faces."""
    used = np.zeros(len(vertices), dtype=bool)
    used[faces.ravel()] = True
    remap = np.cumsum(used) - 1
    return vertices[used], remap[faces]


@dataclass(frozen=True)
class PieceStats:
    """What `remove_small_pieces` did: pieces and faces before, and how many of each it removed."""

    pieces: int
    faces: int
    removed_pieces: int
    removed_faces: int

    @property
    def kept_pieces(self) -> int:
        return self.pieces - self.removed_pieces

    def to_dict(self) -> dict[str, int]:
        return {"pieces": self.pieces, "faces": self.faces, "removed_pieces": self.removed_pieces,
                "removed_faces": self.removed_faces}


def face_pieces(faces: np.ndarray, vertex_count: int) -> tuple[np.ndarray, np.ndarray]:
    """Connected pieces of a triangle mesh.

    faces: (F, 3) int vertex indices. Returns (labels (F,) int64: the piece of each face, numbered
    0..P-1 in order of each piece's first face; sizes (P,) int64: faces per piece).
    """
    from scipy.sparse import coo_matrix  # defers scipy: slow to import
    from scipy.sparse.csgraph import connected_components  # defers scipy: slow to import

    faces = np.asarray(faces, dtype=np.int64).reshape(-1, 3)
    if len(faces) == 0:
        return np.zeros(0, np.int64), np.zeros(0, np.int64)
    # Two edges per triangle connect all three corners; the graph is over vertices.
    rows = np.concatenate([faces[:, 0], faces[:, 1]])
    cols = np.concatenate([faces[:, 1], faces[:, 2]])
    graph = coo_matrix((np.ones(len(rows), np.int8), (rows, cols)), shape=(vertex_count, vertex_count))
    _, vertex_labels = connected_components(graph, directed=False)
    raw = vertex_labels[faces[:, 0]]
    # Renumber so labels depend on face order only (scipy's numbering includes unused vertices).
    _, first, labels = np.unique(raw, return_index=True, return_inverse=True)
    order = np.argsort(first)
    relabel = np.empty_like(order)
    relabel[order] = np.arange(len(order))
    labels = relabel[labels.reshape(-1)]
    return labels.astype(np.int64), np.bincount(labels).astype(np.int64)


def keep_faces(mesh: Mesh, keep: np.ndarray) -> Mesh:
    """The mesh with only the faces where `keep` (F,) is True, unused vertices dropped and renumbered.

    Normals, colours and attributes follow their vertices; dtypes are kept (float32 / int32 for engine meshes).
    """
    keep = np.asarray(keep, dtype=bool)
    faces = np.asarray(mesh.faces)[keep]
    used = np.zeros(len(mesh.vertices), dtype=bool)
    used[faces.ravel()] = True
    remap = (np.cumsum(used) - 1).astype(faces.dtype if len(faces) else np.int32)

    def rows(array):
        return None if array is None else np.asarray(array)[used]

    return Mesh(
        vertices=np.asarray(mesh.vertices)[used],
        faces=remap[faces].astype(np.asarray(mesh.faces).dtype),
        normals=rows(mesh.normals),
        colors=rows(mesh.colors),
        attributes={name: rows(values) for name, values in mesh.attributes.items()},
    )


def remove_small_pieces(mesh: Mesh, min_faces: int = 0, min_fraction: float = 0.0) -> tuple[Mesh, PieceStats]:
    """Drop every piece with fewer than `min_faces` faces or less than `min_fraction` of all faces.

    Both thresholds apply (a piece must pass both to stay); 0 turns a threshold off, and with both
    off the input mesh is returned as it is. The fraction suits captures of any size ("drop anything
    under 1 % of the room"), the face count a fixed notion of noise.
    """
    if min_faces < 0 or not 0.0 <= min_fraction <= 1.0:
        raise ValueError(f"min_faces must be >= 0 and min_fraction in [0, 1], got {min_faces}, {min_fraction}")
    total = int(len(mesh.faces))
    labels, sizes = face_pieces(mesh.faces, len(mesh.vertices))
    if min_faces <= 0 and min_fraction <= 0.0:
        return mesh, PieceStats(len(sizes), total, 0, 0)
    # ceil: "at least 1 % of 250 faces" means 3 faces, not 2.5 rounded down to 2.
    threshold = max(int(min_faces), int(np.ceil(min_fraction * total - 1e-9)))
    keep_piece = sizes >= threshold
    keep = keep_piece[labels]
    stats = PieceStats(len(sizes), total, int((~keep_piece).sum()), int((~keep).sum()))
    if stats.removed_faces == 0:
        return mesh, stats
    return keep_faces(mesh, keep), stats


def subdivide(vertices: np.ndarray, faces: np.ndarray, max_edge: float = 0.05, max_rounds: int = 8):
    """Split triangles with an edge longer than max_edge into 4 (repeatedly), so the point-sampling
    rasteriser covers big ground-truth triangles without holes."""
    v = np.asarray(vertices, np.float64)
    f = np.asarray(faces, np.int64)
    for _ in range(max_rounds):
        tri = v[f]
        edge = np.linalg.norm(tri - np.roll(tri, 1, axis=1), axis=2).max(1)
        big = edge > max_edge
        if not big.any():
            break
        fb = f[big]
        a, b, c = v[fb[:, 0]], v[fb[:, 1]], v[fb[:, 2]]
        n0 = len(v)
        k = len(fb)
        v = np.concatenate([v, (a + b) / 2, (b + c) / 2, (c + a) / 2])
        ab, bc, ca = n0 + np.arange(k), n0 + k + np.arange(k), n0 + 2 * k + np.arange(k)
        new = np.concatenate([np.stack([fb[:, 0], ab, ca], 1), np.stack([ab, fb[:, 1], bc], 1),
                              np.stack([ca, bc, fb[:, 2]], 1), np.stack([ab, bc, ca], 1)])
        f = np.concatenate([f[~big], new])
    return v, f


def merge_duplicate_vertices(vertices: np.ndarray, faces: np.ndarray, tolerance: float = 1e-6) -> tuple[np.ndarray, np.ndarray]:
    """One vertex per position: vertices within the same `tolerance` (metres) cell become one.

    Meshes split per tile, per material or per triangle (glTF, OBJ exports, a subdivision that adds
    each edge's midpoint once per triangle) repeat a vertex where pieces meet, which makes touching
    triangles look disconnected. Returns (unique vertices (U, 3) float64, faces (F', 3) int64) with
    the faces that collapsed (two corners merged into one) dropped.
    """
    vertices, faces, _ = merge_duplicate_vertices_indexed(vertices, faces, tolerance)
    return vertices, faces


def merge_duplicate_vertices_indexed(vertices: np.ndarray, faces: np.ndarray,
                                     tolerance: float = 1e-6) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """`merge_duplicate_vertices`, and for each kept vertex the index (U,) int64 of the input vertex it
    is (to carry per-vertex data along)."""
    vertices = np.asarray(vertices, np.float64).reshape(-1, 3)
    faces = np.asarray(faces, np.int64).reshape(-1, 3)
    if len(vertices) == 0:
        return vertices, faces, np.zeros(0, np.int64)
    _, first, inverse = np.unique(np.round(vertices / tolerance).astype(np.int64), axis=0, return_index=True,
                                  return_inverse=True)
    faces = inverse.reshape(-1)[faces]
    faces = faces[(faces[:, 0] != faces[:, 1]) & (faces[:, 1] != faces[:, 2]) & (faces[:, 0] != faces[:, 2])]
    return vertices[first], faces, first.astype(np.int64)
