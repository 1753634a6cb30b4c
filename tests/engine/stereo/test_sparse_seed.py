"""The sparse points' seed for PatchMatch: the plane through each triangle of visible points."""

import numpy as np

from engine.stereo.sparse_seed import MIN_POINTS, sparse_seed_depth, visible_points

K = np.array([[100.0, 0.0, 80.0], [0.0, 100.0, 60.0], [0.0, 0.0, 1.0]])
SIZE = (160, 120)  # (w, h)


def _camera_at_origin_looking_along(z_axis_world: np.ndarray) -> np.ndarray:
    """A camera-to-world pose at the origin whose optical axis is `z_axis_world` (x stays horizontal)."""
    z = z_axis_world / np.linalg.norm(z_axis_world)
    x = np.cross([0.0, 0.0, 1.0], z)
    x /= np.linalg.norm(x)
    pose = np.eye(4)
    pose[:3, :3] = np.stack([x, np.cross(z, x), z], 1)
    return pose


def test_a_slanted_wall_is_seeded_with_its_own_depth():
    """Points on a wall 3 m ahead, turned 20 deg: every covered pixel's seed is the wall's depth along
    that pixel's ray, computed here by intersecting the ray with the plane."""
    rng = np.random.default_rng(1)
    pose = _camera_at_origin_looking_along(np.array([0.0, 1.0, 0.0]))  # looking along world +y
    normal = np.array([np.sin(np.radians(20)), -np.cos(np.radians(20)), 0.0])  # facing the camera
    base = np.array([0.0, 3.0, 0.0])
    a, b = np.cross(normal, [0.0, 0.0, 1.0]), np.array([0.0, 0.0, 1.0])
    s, t = rng.uniform(-2.5, 2.5, (2, 500))
    points = base + s[:, None] * a + t[:, None] * b

    seed = sparse_seed_depth(points, K, pose, SIZE, (0.3, 10.0))

    v, u = np.nonzero(seed > 0)
    assert len(v) > 0.8 * SIZE[0] * SIZE[1]
    rays_cam = np.stack([(u + 0.5 - K[0, 2]) / K[0, 0], (v + 0.5 - K[1, 2]) / K[1, 1], np.ones(len(u))], 1)
    rays_world = rays_cam @ pose[:3, :3].T
    z = (normal @ base) / (rays_world @ normal)  # ray (z = 1 in the camera) meets the wall at depth z
    np.testing.assert_allclose(seed[v, u], z, rtol=1e-5)


def test_points_hidden_behind_nearer_ones_are_not_seen():
    """A point right behind a box's corner point (same pixel cell, 1 m farther) is taken as hidden;
    one as far but in a cell of its own stays."""
    pose = np.eye(4)  # looking along world +z
    box = np.array([[0.0, 0.0, 1.5]])
    behind = np.array([[0.01, 0.01, 2.5]])
    alone = np.array([[1.0, 0.5, 2.5]])
    uv, z = visible_points(np.concatenate([box, behind, alone]), K, pose, SIZE, (0.3, 10.0))
    assert sorted(np.round(z, 3).tolist()) == [1.5, 2.5]
    assert np.any(np.isclose(uv[:, 0], 100.0 * 1.0 / 2.5 + 80.0))  # the lone far point kept


def test_too_few_points_give_no_seed():
    points = np.array([[x, y, 2.0] for x, y in [(0, 0), (0.3, 0), (0, 0.3)]])
    assert MIN_POINTS > len(points)
    assert not sparse_seed_depth(points, K, np.eye(4), SIZE, (0.3, 10.0)).any()
