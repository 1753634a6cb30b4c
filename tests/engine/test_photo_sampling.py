"""engine/photo_sampling.py: the photo lookups shared by vertex colours and the texture bake."""

from __future__ import annotations

import numpy as np

from engine.geometry.cameras import look_along
from engine.mesh_io import Mesh
from engine.photo_sampling import occlusion_depth, sample_bilinear, visible_points


def test_sample_bilinear_puts_pixel_centres_at_half_integers_and_clamps_the_edges():
    image = np.zeros((2, 3, 3), np.uint8)
    image[:, :, 0] = [[0, 100, 200], [0, 100, 200]]
    out = sample_bilinear(image, np.array([0.5, 1.0, 2.5, 9.0]), np.array([0.5, 0.5, 1.5, -3.0]))
    assert out.shape == (4, 3) and out.dtype == np.float32
    np.testing.assert_allclose(out[:, 0], [0, 50, 200, 200], atol=1)
    assert sample_bilinear(image, np.zeros(0), np.zeros(0)).shape == (0, 3)


def _square(z: float, size: float) -> Mesh:
    h = size / 2
    vertices = np.array([[-h, -h, z], [h, -h, z], [h, h, z], [-h, h, z]], np.float32)
    faces = np.array([[0, 1, 2], [0, 2, 3]], np.int32)
    normals = np.tile(np.array([0, 0, -1], np.float32), (4, 1))  # toward the camera below
    return Mesh(vertices, faces, normals)


def test_visible_points_drops_what_a_nearer_surface_hides_and_what_faces_away():
    pose = look_along(np.zeros(3), np.array([0.0, 0.0, 1.0]))  # at the origin, looking up +Z
    K = np.array([[50.0, 0, 50], [0, 50, 50], [0, 0, 1]])
    occluder = _square(1.0, 0.4)  # hides the middle of the wall at z = 2
    depth = occlusion_depth(occluder, K, pose, (100, 100))
    points = np.array([[0.0, 0.0, 2.0], [1.0, 1.0, 2.0], [1.0, 1.0, 2.0], [0.0, 0.0, 0.5]])
    normals = np.array([[0, 0, -1], [0, 0, -1], [0, 0, 1], [0, 0, -1]], np.float64)
    ids, u, v, cosine, z = visible_points(points, normals, K, pose, (100, 100), depth, tolerance=0.05)
    # 0: behind the occluder; 1: seen; 2: faces away; 3: in front of the occluder, seen.
    assert sorted(ids.tolist()) == [1, 3]
    assert np.all(cosine > 0) and np.all((u >= 0) & (u < 100) & (v >= 0) & (v < 100))
    np.testing.assert_allclose(z[ids.tolist().index(3)], 0.5)
