"""Colour renders of meshes from posed cameras, checked against geometry computed here by hand."""

from __future__ import annotations

import numpy as np
import pytest

from engine.errors import VortxError
from engine.eval.view_render import render_surface, render_textured, render_vertex_colours
from engine.geometry.depth_render import render_depth
from engine.mesh_io import Mesh
from engine.texture.textured_mesh import TexturedMesh

SIZE = (64, 64)
K = np.array([[64.0, 0, 32], [0, 64, 32], [0, 0, 1]])
CAMERA = np.eye(4)  # at the origin looking along +z, image x = +x, image y = +y


def quad(corners: np.ndarray, uv_corners: np.ndarray, texture: np.ndarray) -> TexturedMesh:
    """Two triangles over corners (4, 3) in order top-left, top-right, bottom-right, bottom-left."""
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    return TexturedMesh(vertices=corners.astype(np.float32), faces=faces, normals=np.tile([[0, 0, -1.0]], (4, 1)).astype(np.float32),
                        uvs=uv_corners.astype(np.float32), texture=texture)


def square_at(depth: float, lo: float, hi: float) -> np.ndarray:
    """Corners of the square whose image is the pixel-edge square [lo, hi)^2, at planar depth `depth`."""
    a, b = (lo - 32) / 64 * depth, (hi - 32) / 64 * depth
    return np.array([[a, a, depth], [b, a, depth], [b, b, depth], [a, b, depth]])


def test_a_textured_quad_seen_head_on_shows_the_texture_texel_for_pixel():
    rng = np.random.default_rng(0)
    texture = rng.integers(0, 256, (32, 32, 3), dtype=np.uint8)
    # The quad covers pixels 16..47 exactly; its top-left corner carries uv (0, 1): the texture's row 0.
    uvs = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    image, mask = render_textured(quad(square_at(2.0, 16, 48), uvs, texture), K, CAMERA, SIZE)
    # Pixel centres fall on texel centres, so bilinear lookup returns the texels themselves.
    np.testing.assert_array_equal(image[16:48, 16:48], texture)
    assert mask[16:48, 16:48].all()
    outside = np.ones(mask.shape, bool)
    outside[16:49, 16:49] = False  # the closing edges lie on pixel boundaries 48: those pixels may be touched
    assert not mask[outside].any() and not image[outside].any()


def test_a_tilted_checkerboard_is_perspective_correct():
    """A checkerboard on a plane receding to the right: each pixel shows the square its ray hits."""
    squares, texels = 8, 64
    cell = texels // squares
    parity = (np.arange(texels)[:, None] // cell + np.arange(texels)[None] // cell) % 2
    texture = np.where(parity[..., None] == 1, 255, 0).astype(np.uint8).repeat(3, axis=2)
    # Plane points P(s, t) = A + s (B - A) + t (D - A), s, t in [0, 1]; uv = (s, 1 - t).
    A, B, D = np.array([-1.0, -1.0, 1.5]), np.array([1.0, -1.0, 4.0]), np.array([-1.0, 1.0, 1.5])
    corners = np.array([A, B, B + D - A, D])
    uvs = np.array([[0.0, 1.0], [1.0, 1.0], [1.0, 0.0], [0.0, 0.0]])
    image, mask = render_textured(quad(corners, uvs, texture), K, CAMERA, SIZE)
    # Independent: intersect each pixel's ray with the plane, read the square it lands in.
    rows, cols = np.nonzero(mask)
    rays = np.linalg.solve(K, np.stack([cols + 0.5, rows + 0.5, np.ones(len(rows))]))
    e1, e2 = B - A, D - A
    n = np.cross(e1, e2)
    t_ray = (n @ A) / (n @ rays)
    hit = rays * t_ray - A[:, None]
    st = np.linalg.lstsq(np.stack([e1, e2], 1), hit, rcond=None)[0]  # (2, N)
    col_t, row_t = st[0] * texels, st[1] * texels  # texel coordinates (row 0 = t 0 = uv v 1)
    expected = np.where(((np.floor(col_t) // cell + np.floor(row_t) // cell) % 2) == 1, 255, 0)
    # Away from square borders (bilinear blends there) and the quad's rim (pixels it overlaps whose
    # centre lies just outside show the clipped rim) every pixel must match.
    on_quad = (st > 0).all(axis=0) & (st < 1).all(axis=0)
    clear = on_quad & (np.abs(col_t / cell - np.round(col_t / cell)) * cell > 1.0) & (np.abs(row_t / cell - np.round(row_t / cell)) * cell > 1.0)
    assert clear.sum() > 500
    np.testing.assert_array_equal(image[rows, cols, 0][clear], expected[clear])
    # Affine (screen-space) interpolation would put the squares' borders elsewhere: the receding half
    # of the plane has squares narrower on screen, so their count along the middle row is telling.
    middle = image[32, mask[32], 0].astype(int)
    assert np.count_nonzero(np.diff(middle)) >= squares - 1


def test_coverage_is_the_projected_polygon():
    """Every pixel whose centre lies inside the projected triangle is covered; every covered pixel
    overlaps it (its centre within half a pixel diagonal)."""
    tri = np.array([[-0.6, -0.4, 2.0], [0.7, -0.2, 2.5], [-0.1, 0.6, 1.8]])
    mesh = Mesh(vertices=tri.astype(np.float32), faces=np.array([[0, 1, 2]], np.int32),
                colors=np.array([[1.0, 0, 0], [0, 1.0, 0], [0, 0, 1.0]], np.float32))
    image, mask = render_vertex_colours(mesh, K, CAMERA, SIZE)
    p = (K @ tri.T).T
    p = p[:, :2] / p[:, 2:]
    jj, ii = np.meshgrid(np.arange(64) + 0.5, np.arange(64) + 0.5)
    q = np.stack([jj, ii], -1)

    def signed(a, b):  # distance of pixel centres from the edge a -> b (positive inside, counter-clockwise)
        d = b - a
        return ((q[..., 0] - a[0]) * d[1] - (q[..., 1] - a[1]) * d[0]) / np.hypot(*d)

    dist = np.stack([signed(p[0], p[1]), signed(p[1], p[2]), signed(p[2], p[0])])
    dist = dist if (dist > 0).all(axis=0).any() else -dist  # whichever orientation the screen triangle has
    inside = (dist > 0).all(axis=0)
    assert inside.sum() > 300
    assert mask[inside].all()
    assert (dist[:, mask] > -np.sqrt(0.5) - 1e-6).all()
    # Vertex colours: red + green + blue shares are the pixel centre's perspective-correct barycentrics,
    # which sum to one: each covered pixel's channels add up to ~255.
    total = image[inside].astype(int).sum(axis=1)
    assert np.all(np.abs(total - 255) <= 2)


def test_vertex_colours_interpolate_and_the_nearest_surface_wins():
    near = square_at(1.0, 8, 40)
    far = square_at(3.0, 24, 56)
    vertices = np.concatenate([near, far]).astype(np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3], [4, 5, 6], [4, 6, 7]], np.int32)
    colours = np.array([[1.0, 0, 0]] * 4 + [[0, 0, 1.0]] * 4, np.float32)
    image, mask = render_vertex_colours(Mesh(vertices, faces, colors=colours), K, CAMERA, SIZE)
    np.testing.assert_array_equal(image[30, 30], [255, 0, 0])  # both cover it: the near red one in front
    np.testing.assert_array_equal(image[50, 50], [0, 0, 255])
    assert not mask[2, 2] and mask[30, 30] and mask[50, 50]
    # A horizontal colour ramp on a fronto-parallel quad is linear in the image.
    ramp = np.array([[0.0, 0, 0], [1.0, 0, 0], [1.0, 0, 0], [0.0, 0, 0]], np.float32)
    image, _ = render_vertex_colours(Mesh(square_at(2.0, 0, 64).astype(np.float32), faces[:2], colors=ramp), K, CAMERA, SIZE)
    np.testing.assert_allclose(image[20, :, 0], np.round(255 * (np.arange(64) + 0.5) / 64), atol=1)
    with pytest.raises(VortxError, match="no vertex colours"):
        render_vertex_colours(Mesh(vertices, faces), K, CAMERA, SIZE)


def test_surface_depth_agrees_with_render_depth():
    tri = np.array([[-0.4, -0.4, 2.0], [0.4, -0.4, 3.0], [0.0, 0.4, 2.5]])  # < 32 px edges: one lattice for both
    faces = np.array([[0, 1, 2]])
    face_id, bary, depth = render_surface(tri, faces, K, CAMERA, SIZE)
    reference = render_depth(tri, faces, K, CAMERA, SIZE)
    assert np.array_equal(face_id >= 0, np.isfinite(reference))
    both = np.isfinite(reference)
    # render_depth holds the nearest lattice sample in the pixel, render_surface the pixel centre's
    # point: they differ by at most the depth change across a pixel (1 m over ~25 pixels here).
    assert np.abs(depth[both] - reference[both]).max() < 0.05
    # Where the pixel centre lies inside, the barycentric point projects back onto the pixel centre.
    rows, cols = np.nonzero((bary > 1e-3).all(axis=2) & both)
    points = np.einsum("nk,kc->nc", bary[rows, cols].astype(np.float64), tri)
    projected = (K @ points.T).T
    np.testing.assert_allclose(projected[:, 0] / projected[:, 2], cols + 0.5, atol=1e-3)
    np.testing.assert_allclose(projected[:, 1] / projected[:, 2], rows + 0.5, atol=1e-3)
    np.testing.assert_allclose(depth[rows, cols], points[:, 2], atol=1e-5)
    np.testing.assert_allclose(bary[both].sum(axis=1), 1.0, atol=1e-5)
    assert (bary[both] >= 0).all()
