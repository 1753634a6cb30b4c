"""The reference's scene points that sources are chosen over: a grid of its pixels, lifted to a depth."""

import numpy as np

from engine.stereo.source_views import SCENE_SAMPLES, scene_points

K = np.array([[100.0, 0.0, 80.0], [0.0, 100.0, 60.0], [0.0, 0.0, 1.0]])
SIZE = (160, 120)


def test_grid_pixels_a_depth_map_covers_take_its_depth_and_the_rest_the_middle_depth():
    pose = np.eye(4)
    pose[:3, 3] = [1.0, 2.0, 0.5]
    depth_map = np.zeros((SIZE[1], SIZE[0]), np.float32)
    depth_map[:, : SIZE[0] // 2] = 1.25  # the left half seen by the sparse points

    points = scene_points(K, pose, SIZE, 3.0, depth_map)
    plain = scene_points(K, pose, SIZE, 3.0)

    assert points.shape == plain.shape == (SCENE_SAMPLES * SCENE_SAMPLES, 3)
    z = points[:, 2] - pose[2, 3]  # camera z (the camera looks along world +z here)
    u = K[0, 0] * (points[:, 0] - pose[0, 3]) / z + K[0, 2]
    left = u < SIZE[0] / 2
    np.testing.assert_allclose(z[left], 1.25, rtol=1e-6)
    np.testing.assert_allclose(z[~left], 3.0, rtol=1e-6)
    np.testing.assert_allclose(points[~left], plain[~left])
