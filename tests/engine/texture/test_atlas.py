"""The xatlas UV atlas: every face kept, UVs in the unit square, charts that do not overlap."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import VortxError
from engine.recon.mesh import vertex_normals
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
