"""The xatlas UV atlas: every face kept, UVs in the unit square, charts that do not overlap."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import VortxError
from engine.meshops import vertex_normals
from engine.texture.atlas import uv_atlas
from engine.texture.texels import rasterise_uv


def box(n: int = 6):
    """A closed unit cube of 12 n^2 triangles."""
    from skimage.measure import marching_cubes

    grid = np.pad(np.ones((n, n, n), np.float32), 1)
    verts, faces, _, _ = marching_cubes(grid, 0.5)
    return verts.astype(np.float32) / n, faces.astype(np.int32)


def test_atlas_keeps_faces_and_vertices_and_packs_without_overlap():
    vertices, faces = box()
    atlas = uv_atlas(vertices, faces, vertex_normals(vertices, faces), texture_size=512, padding=2)
    assert atlas.faces.shape == faces.shape
    # Each atlas vertex copies a source vertex, and each face is the source face through that map.
    np.testing.assert_array_equal(atlas.source_vertex[atlas.faces], faces)
    assert atlas.uvs.min() >= 0 and atlas.uvs.max() <= 1 and atlas.charts >= 6
    # No overlap: the texels the triangles cover add up to their UV area (overlaps would count twice).
    uv_tri = atlas.uvs[atlas.faces].astype(np.float64) * 512
    area = 0.5 * np.abs(np.cross(uv_tri[:, 1] - uv_tri[:, 0], uv_tri[:, 2] - uv_tri[:, 0])).sum()
    covered = len(rasterise_uv(atlas.uvs, atlas.faces, (512, 512)))
    assert covered == pytest.approx(area, rel=0.03)


def test_an_empty_mesh_is_refused():
    with pytest.raises(VortxError, match="no faces"):
        uv_atlas(np.zeros((0, 3), np.float32), np.zeros((0, 3), np.int32), None, 512, 2)


@pytest.mark.parametrize("name", ["quad", "triangle", "low-poly box"])
def test_low_poly_meshes_get_an_atlas(name):
    """The charting copy is smoothed without shrinking: a two-triangle wall must not collapse to a point."""
    if name == "quad":
        vertices = np.float32([[0, 0, 0], [2, 0, 0], [2, 0, 1], [0, 0, 1]])
        faces = np.int32([[0, 1, 2], [0, 2, 3]])
    elif name == "triangle":
        vertices, faces = np.float32([[0, 0, 0], [1, 0, 0], [0, 0, 1]]), np.int32([[0, 1, 2]])
    else:
        vertices, faces = box(1)
    atlas = uv_atlas(vertices, faces, None, texture_size=512, padding=4)
    uv_tri = atlas.uvs[atlas.faces].astype(np.float64)
    assert (0.5 * np.abs(np.cross(uv_tri[:, 1] - uv_tri[:, 0], uv_tri[:, 2] - uv_tri[:, 0])) > 0).all()


def test_the_atlas_fills_the_texture_at_one_density():
    """UVs are in texture texels: the charts span the square (not squeezed into part of it), and every
    face gets the same texels per square metre (a flat grid, which smoothing leaves as it is)."""
    n = 40
    s, t = np.meshgrid(np.linspace(0, 3, n + 1), np.linspace(0, 2, n + 1), indexing="ij")
    vertices = np.stack([s.ravel(), np.zeros(s.size), t.ravel()], 1).astype(np.float32)
    idx = np.arange((n + 1) ** 2).reshape(n + 1, n + 1)
    a, b, c, d = idx[:-1, :-1].ravel(), idx[1:, :-1].ravel(), idx[:-1, 1:].ravel(), idx[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)]).astype(np.int32)
    for size in (512, 2048):
        atlas = uv_atlas(vertices, faces, None, texture_size=size, padding=4)
        assert atlas.uvs.max() <= 1.0 and atlas.uvs.max(axis=0).max() > 0.85
        uv_tri = atlas.uvs[atlas.faces].astype(np.float64)
        uv_area = 0.5 * np.abs(np.cross(uv_tri[:, 1] - uv_tri[:, 0], uv_tri[:, 2] - uv_tri[:, 0]))
        tri = vertices[faces].astype(np.float64)
        area = 0.5 * np.linalg.norm(np.cross(tri[:, 1] - tri[:, 0], tri[:, 2] - tri[:, 0]), axis=1)
        ratio = uv_area / area
        assert ratio.max() / ratio.min() < 1.2


def fins_and_folds():
    """A strip of 4 quads plus a fin (a third face on an inner edge) and a folded face (an edge's
    second face wound the same way as its first), as edge collapses leave them."""
    vertices = np.float32([[x, 0, z] for z in (0, 1) for x in range(5)] + [[1, 1, 0.5], [2, -1, 0.5]])
    strip = [[0, 1, 6], [0, 6, 5], [1, 2, 7], [1, 7, 6], [2, 3, 8], [2, 8, 7], [3, 4, 9], [3, 9, 8]]
    fin, fold = [1, 6, 10], [2, 8, 11]  # edge 1-6 gets a third face; 2->8 runs the way 2 8 7 runs it
    return vertices, np.int32(strip + [fin, fold])


def test_edges_in_more_than_two_faces_and_folds_are_cut_apart_for_xatlas():
    from engine.texture.atlas import manifold_faces

    vertices, faces = fins_and_folds()
    split, source = manifold_faces(faces.astype(np.int64), len(vertices))
    np.testing.assert_array_equal(source[split], faces)  # the same triangles, some on vertex copies
    directed = np.concatenate([split[:, [0, 1]], split[:, [1, 2]], split[:, [2, 0]]])
    assert len(np.unique(directed, axis=0)) == len(directed)  # no edge twice the same way
    _, uses = np.unique(np.sort(directed, axis=1), axis=0, return_counts=True)
    assert uses.max() == 2
    assert (split[:8] == faces[:8]).all() and (split[8:] >= len(vertices)).all()  # only fin and fold moved

    atlas = uv_atlas(vertices, faces, None, texture_size=512, padding=2)
    np.testing.assert_array_equal(atlas.source_vertex[atlas.faces], faces)
    uv_tri = atlas.uvs[atlas.faces].astype(np.float64) * 512
    area = 0.5 * np.abs(np.cross(uv_tri[:, 1] - uv_tri[:, 0], uv_tri[:, 2] - uv_tri[:, 0]))
    assert (area > 0).all()  # the fin and the fold get texels of their own
    covered = len(rasterise_uv(atlas.uvs, atlas.faces, (512, 512)))
    assert covered == pytest.approx(area.sum(), rel=0.05)  # and overlap nothing


def test_nan_positions_are_refused_with_what_to_do():
    vertices, faces = box(2)
    vertices[3] = np.nan
    with pytest.raises(VortxError, match=r"NaN or infinite positions.*Clean Up"):
        uv_atlas(vertices, faces, None, texture_size=512, padding=2)
