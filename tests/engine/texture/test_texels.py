"""Texel rasterisation in UV space, against the texel-centre rule computed independently."""

from __future__ import annotations

import numpy as np

from engine.texture.texels import rasterise_uv


def test_a_full_square_covers_every_texel_once_at_its_centre():
    uvs = np.array([[0, 0], [1, 0], [1, 1], [0, 1]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    W, H = 16, 8
    texels = rasterise_uv(uvs, faces, (W, H))
    assert len(texels) == W * H
    assert len(set(zip(texels.rows.tolist(), texels.cols.tolist()))) == W * H
    uv = texels.interpolate(uvs, faces)
    # Texel (r, c) centre: u = (c + 0.5) / W, v = 1 - (r + 0.5) / H (v up, row 0 at the top).
    np.testing.assert_allclose(uv[:, 0], (texels.cols + 0.5) / W, atol=1e-6)
    np.testing.assert_allclose(uv[:, 1], 1 - (texels.rows + 0.5) / H, atol=1e-6)


def test_a_triangle_covers_exactly_the_texels_whose_centre_it_contains():
    rng = np.random.default_rng(3)
    W = H = 64
    for _ in range(20):
        tri = rng.uniform(0.05, 0.95, (3, 2)).astype(np.float32)
        texels = rasterise_uv(tri, np.array([[0, 1, 2]], np.int32), (W, H))
        cc, rr = np.meshgrid(np.arange(W), np.arange(H))
        u, v = (cc + 0.5) / W, 1 - (rr + 0.5) / H
        # Inside test by the signs of the three edge functions (either winding).
        def edge(a, b):
            return (b[0] - a[0]) * (v - a[1]) - (b[1] - a[1]) * (u - a[0])
        e = np.stack([edge(tri[0], tri[1]), edge(tri[1], tri[2]), edge(tri[2], tri[0])])
        inside = (e >= 0).all(0) | (e <= 0).all(0)
        got = np.zeros((H, W), bool)
        got[texels.rows, texels.cols] = True
        # Texel centres exactly on an edge may go either way; there are none at random corners.
        assert (got == inside).mean() > 0.999 and abs(int(got.sum()) - int(inside.sum())) <= 1


def test_large_and_small_triangles_together_match_a_brute_force_count():
    """Triangles of very different sizes fall into different size bins; each must still get exactly
    the texel centres inside it (edges included), as counted texel by texel."""
    uvs = np.array([[0, 0], [0.5, 0], [0, 0.5], [0.6, 0.6], [0.61, 0.6], [0.6, 0.61]], np.float32)
    faces = np.array([[0, 1, 2], [3, 4, 5]], np.int32)
    W = H = 1024
    texels = rasterise_uv(uvs, faces, (W, H))
    cc, rr = np.meshgrid(np.arange(W), np.arange(H))
    x, y = cc + 0.5, H - (rr + 0.5)  # texel centres in texel units, y up
    for f, tri in enumerate(uvs[faces].astype(np.float64) * W):
        (x0, y0), (x1, y1), (x2, y2) = tri
        det = (x1 - x0) * (y2 - y0) - (y1 - y0) * (x2 - x0)
        b1 = ((x - x0) * (y2 - y0) - (y - y0) * (x2 - x0)) / det
        b2 = ((x1 - x0) * (y - y0) - (y1 - y0) * (x - x0)) / det
        inside = (b1 >= -1e-9) & (b2 >= -1e-9) & (b1 + b2 <= 1 + 1e-9)
        assert int((texels.face == f).sum()) == int(inside.sum())
