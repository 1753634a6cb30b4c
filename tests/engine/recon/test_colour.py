"""Occlusion-aware vertex colouring: the mesh's own depth decides which views a vertex takes colour from."""

from __future__ import annotations

import numpy as np
import pytest

from engine.mesh_io import Mesh
from engine.geometry.depth_render import render_depth
from engine.photo_sampling import UNSEEN_GREY
from engine.recon.colour import ColourView, colour_vertices
from engine.geometry.cameras import look_along as look_pose

K = np.array([[100.0, 0, 50], [0, 100, 50], [0, 0, 1]])  # 100 x 100 image, half-angle 26.6 deg
SIZE = (100, 100)


def wall(x: float, half: float, n: int) -> tuple[np.ndarray, np.ndarray]:
    """A square grid in the plane X = x, |y|, |z| <= half, facing -x (toward cameras at smaller x)."""
    s = np.linspace(-half, half, n)
    y, z = np.meshgrid(s, s, indexing="ij")
    vertices = np.stack([np.full(y.size, x), y.ravel(), z.ravel()], axis=1)
    ids = np.arange(n * n).reshape(n, n)
    a, b, c, d = ids[:-1, :-1].ravel(), ids[1:, :-1].ravel(), ids[:-1, 1:].ravel(), ids[1:, 1:].ravel()
    faces = np.concatenate([np.stack([a, b, d], 1), np.stack([a, d, c], 1)])
    return vertices, faces


def test_render_depth_is_planar_depth_without_holes():
    vertices, faces = wall(2.0, 0.5, 9)
    camera = look_pose(np.zeros(3), np.array([1.0, 0, 0]))
    depth = render_depth(vertices, faces, K, camera, SIZE)
    # The wall spans u, v in [25, 75): every pixel there must be hit, at planar depth 2.
    inner = depth[26:74, 26:74]
    assert np.isfinite(inner).all()
    np.testing.assert_allclose(inner, 2.0, atol=1e-5)
    assert np.isinf(depth[:20]).all() and np.isinf(depth[:, 80:]).all()
    # A tilted wall: depth grows across the image as the plane recedes, still without holes.
    tilted = vertices.copy()
    tilted[:, 0] += 0.5 * tilted[:, 1]  # x = 2 + 0.5 y; image right = world -y, so depth falls to the right
    depth = render_depth(tilted, faces, K, camera, SIZE)
    row = depth[50, 30:70]
    assert np.isfinite(row).all() and np.all(np.diff(row) < 0)


@pytest.mark.parametrize("pixels", [100, 320])  # 320: the occlusion z-buffer is rendered at fewer pixels
def test_a_vertex_hidden_by_a_wall_does_not_take_that_views_colour(pixels):
    far_v, far_f = wall(3.0, 2.0, 41)  # 10 cm spacing
    near_v, near_f = wall(1.5, 0.3, 7)  # occluder in front of the far wall's centre, as seen from A
    vertices = np.concatenate([far_v, near_v]).astype(np.float32)
    faces = np.concatenate([far_f, near_f + len(far_v)]).astype(np.int32)
    normals = np.tile(np.array([[-1.0, 0.0, 0.0]], np.float32), (len(vertices), 1))
    mesh = Mesh(vertices, faces, normals)

    k = np.diag([pixels / 100, pixels / 100, 1.0]) @ K  # same field of view at any size

    def solid(rgb: tuple[int, int, int]) -> np.ndarray:
        return np.tile(np.array(rgb, dtype=np.uint8)[None, None], (pixels, pixels, 1))

    view_a = ColourView(solid((0, 255, 0)), k, look_pose(np.zeros(3), np.array([1.0, 0, 0])))  # green, behind the occluder
    view_b = ColourView(solid((255, 0, 0)), k, look_pose(np.array([2.0, 0, 0]), np.array([1.0, 0, 0])))  # red, past it
    colours = colour_vertices(mesh, [view_a, view_b], tolerance=0.08)

    far, near = colours[: len(far_v)], colours[len(far_v):]
    y, z = far_v[:, 1], far_v[:, 2]
    # Behind the occluder from A (its shadow on the far wall spans |y|, |z| < 0.6), seen by B: pure red.
    hidden_from_a = (np.abs(y) < 0.5) & (np.abs(z) < 0.5)
    assert hidden_from_a.sum() > 50
    assert np.abs(far[hidden_from_a] - [1, 0, 0]).max() < 1e-6
    # Seen by A only (inside A's frustum of half-width 1.5 m, outside B's 0.5 m): pure green.
    only_a = (np.abs(y) > 0.7) & (np.abs(y) < 1.4) & (np.abs(z) < 1.4)
    assert only_a.sum() > 50
    assert np.abs(far[only_a] - [0, 1, 0]).max() < 1e-6
    # Outside both frusta: grey. The occluder faces A only (B has its back to it): green.
    unseen = (np.abs(y) > 1.6) | (np.abs(z) > 1.6)
    assert unseen.sum() > 50 and np.all(far[unseen] == UNSEEN_GREY)
    assert np.abs(near - [0, 1, 0]).max() < 1e-6
    # Without the occluder in the mesh, the same far-wall vertices mix both views.
    alone = Mesh(far_v.astype(np.float32), far_f.astype(np.int32), normals[: len(far_v)])
    mixed = colour_vertices(alone, [view_a, view_b], tolerance=0.08)[hidden_from_a]
    assert np.all(mixed[:, 0] > 0.2) and np.all(mixed[:, 1] > 0.2)
