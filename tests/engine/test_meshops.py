"""engine.meshops: connected pieces and dropping small ones, on hand-built meshes."""

from __future__ import annotations

import numpy as np
import pytest

from engine.mesh_io import Mesh
from engine.meshops import face_pieces, keep_faces, remove_small_pieces


def grid_piece(n: int, offset: tuple[float, float, float]) -> tuple[np.ndarray, np.ndarray]:
    """An n x n quad grid split into 2 n^2 triangles (one connected piece), shifted by `offset`."""
    ys, xs = np.mgrid[0 : n + 1, 0 : n + 1]
    vertices = np.stack([xs.ravel(), ys.ravel(), np.zeros(xs.size)], axis=1).astype(np.float32) + np.float32(offset)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, :-1].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    return vertices, faces


def mesh_of(pieces: list[tuple[np.ndarray, np.ndarray]], interleave: bool = False) -> Mesh:
    vertices, faces, start = [], [], 0
    for v, f in pieces:
        vertices.append(v)
        faces.append(f + start)
        start += len(v)
    v = np.concatenate(vertices)
    f = np.concatenate(faces).astype(np.int32)
    if interleave:  # pieces' faces mixed in the face list, as marching cubes emits them
        f = f[np.random.default_rng(0).permutation(len(f))]
    colors = np.random.default_rng(1).random((len(v), 3)).astype(np.float32)
    normals = np.tile(np.float32([0, 0, 1]), (len(v), 1))
    return Mesh(vertices=v, faces=f, normals=normals, colors=colors)


def test_pieces_are_found_and_sized() -> None:
    big, small, tiny = grid_piece(10, (0, 0, 0)), grid_piece(2, (20, 0, 0)), grid_piece(1, (0, 20, 0))
    mesh = mesh_of([big, small, tiny], interleave=True)
    labels, sizes = face_pieces(mesh.faces, len(mesh.vertices))
    assert sorted(sizes.tolist()) == [2, 8, 200]
    assert sizes.sum() == len(mesh.faces) and labels.shape == (len(mesh.faces),)
    assert labels[0] == 0  # numbered in order of first face
    # Each piece's faces touch only that piece's vertices (0..120 big, 121..129 small, 130.. tiny).
    for piece in range(3):
        used = np.unique(mesh.faces[labels == piece])
        owner = np.digitize(used, [121, 130])
        assert len(np.unique(owner)) == 1


def test_faces_sharing_only_a_vertex_are_one_piece() -> None:
    vertices = np.float32([[0, 0, 0], [1, 0, 0], [0, 1, 0], [-1, 0, 0], [0, -1, 0]])
    faces = np.int32([[0, 1, 2], [0, 3, 4]])
    _, sizes = face_pieces(faces, len(vertices))
    assert sizes.tolist() == [2]


@pytest.mark.parametrize("min_faces, min_fraction, kept", [(0, 0.0, [200, 8, 2]), (3, 0.0, [200, 8]), (0, 0.05, [200]),
                                                          (9, 0.0, [200]), (201, 0.0, [])])
def test_remove_small_pieces_thresholds(min_faces: int, min_fraction: float, kept: list[int]) -> None:
    mesh = mesh_of([grid_piece(10, (0, 0, 0)), grid_piece(2, (20, 0, 0)), grid_piece(1, (0, 20, 0))], interleave=True)
    cleaned, stats = remove_small_pieces(mesh, min_faces, min_fraction)
    _, sizes = face_pieces(cleaned.faces, len(cleaned.vertices))
    assert sorted(sizes.tolist(), reverse=True) == kept
    assert stats.pieces == 3 and stats.removed_pieces == 3 - len(kept)
    assert stats.removed_faces == 210 - sum(kept) == len(mesh.faces) - len(cleaned.faces)
    assert cleaned.faces.dtype == np.int32 and cleaned.vertices.dtype == np.float32
    if kept:  # no vertex left unused, none out of range
        assert np.array_equal(np.unique(cleaned.faces), np.arange(len(cleaned.vertices)))


def test_kept_faces_keep_their_positions_colours_and_normals() -> None:
    mesh = mesh_of([grid_piece(4, (0, 0, 0)), grid_piece(1, (9, 9, 9))], interleave=True)
    cleaned, _ = remove_small_pieces(mesh, min_faces=3)
    before = {tuple(np.round(mesh.vertices[f].ravel(), 5)) for f in mesh.faces}
    after = {tuple(np.round(cleaned.vertices[f].ravel(), 5)) for f in cleaned.faces}
    assert after < before and len(after) == 32  # the same triangles, in the same winding
    # Each kept vertex carries its own colour and normal along.
    lookup = {tuple(v): c for v, c in zip(mesh.vertices.tolist(), mesh.colors.tolist())}
    for v, c in zip(cleaned.vertices.tolist(), cleaned.colors.tolist()):
        assert lookup[tuple(v)] == c
    assert cleaned.normals.shape == cleaned.vertices.shape


def test_nothing_to_remove_returns_the_same_mesh_and_rejects_bad_thresholds() -> None:
    mesh = mesh_of([grid_piece(3, (0, 0, 0))])
    same, stats = remove_small_pieces(mesh, min_faces=5)
    assert same is mesh and stats.removed_faces == 0 and stats.kept_pieces == 1
    empty = Mesh(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32))
    assert remove_small_pieces(empty, 10)[1].pieces == 0
    assert len(keep_faces(mesh, np.zeros(len(mesh.faces), bool)).vertices) == 0
    with pytest.raises(ValueError):
        remove_small_pieces(mesh, min_fraction=1.5)
