"""Depth maps smoothed along PatchMatch's planes (engine/stereo/plane_smoothing.py) against exact
geometry: a noisy slanted floor comes out nearer its true plane with truer normals, a box in front of a
wall keeps its edge, no depth is added or removed, and the vectorised rule equals a per-pixel loop."""

from __future__ import annotations

import numpy as np

from engine.geometry.depth_normals import depth_normals
from engine.stereo.plane_smoothing import smooth_along_planes

W, H, FOCAL = 64, 48, 50.0
K = np.array([[FOCAL, 0, W / 2], [0, FOCAL, H / 2], [0, 0, 1]])


def _rays() -> np.ndarray:
    """(H, W, 3) rays through the pixel centres, z = 1."""
    v, u = np.mgrid[0:H, 0:W] + 0.5
    return np.stack([(u - K[0, 2]) / FOCAL, (v - K[1, 2]) / FOCAL, np.ones((H, W))], -1)


def _plane_depth(normal: np.ndarray, offset: float) -> np.ndarray:
    """(H, W) depth of the plane normal . X = offset along every pixel's ray."""
    return offset / (_rays() @ normal)


def _facing(normal: np.ndarray) -> np.ndarray:
    return -normal / np.linalg.norm(normal)  # towards the camera at +z


def test_a_noisy_slanted_floor_comes_nearer_its_plane_with_truer_normals() -> None:
    rng = np.random.default_rng(0)
    normal = _facing(np.array([0.0, 0.8, 0.6]))  # a floor seen from above, 37 deg from the view axis
    truth = _plane_depth(normal, float(normal @ np.array([0.0, 0.0, 2.5])))
    noisy = (truth * (1 + rng.normal(0, 0.02, truth.shape))).astype(np.float32)  # PatchMatch's few per cent
    normals = normal + rng.normal(0, 0.1, (H, W, 3))  # each pixel's own plane, tilted by ~6 deg
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    smoothed = smooth_along_planes(noisy, normals.astype(np.float32), K)
    inner = (slice(4, -4), slice(4, -4))
    before = np.abs(noisy - truth)[inner].mean() / truth[inner].mean()
    after = np.abs(smoothed - truth)[inner].mean() / truth[inner].mean()
    assert after < 0.5 * before
    true_n, _ = depth_normals(truth.astype(np.float32), K)

    def within_30deg(depth: np.ndarray) -> float:
        n, ok = depth_normals(depth, K)
        return float(np.mean(np.abs(np.sum(n * true_n, -1))[ok] > np.cos(np.radians(30))))

    assert within_30deg(noisy) < 0.8 and within_30deg(smoothed) > 0.95


def test_a_box_in_front_of_a_wall_keeps_its_edge() -> None:
    wall = np.full((H, W), 3.0)
    depth = wall.copy()
    depth[:, W // 2:] = 2.0  # a box face a metre nearer: 33 % of the depth, far beyond the agreement
    normals = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (H, W, 3)).astype(np.float32)
    smoothed = smooth_along_planes(depth.astype(np.float32), normals, K)
    np.testing.assert_allclose(smoothed, depth, rtol=1e-6)


def test_no_depth_is_added_or_removed() -> None:
    rng = np.random.default_rng(1)
    depth = rng.uniform(1.9, 2.1, (H, W)).astype(np.float32)
    depth[rng.random((H, W)) < 0.3] = 0.0
    normals = np.broadcast_to(np.array([0.0, 0.0, -1.0]), (H, W, 3)).astype(np.float32)
    smoothed = smooth_along_planes(depth, normals, K)
    np.testing.assert_array_equal(smoothed > 0, depth > 0)


def test_the_rule_pixel_by_pixel() -> None:
    """One pass against a direct loop: the mean over neighbours within the radius whose plane meets
    the pixel's ray within the agreement of its depth (its own plane included)."""
    rng = np.random.default_rng(2)
    h, w, radius, agreement = 9, 11, 2, 0.05
    K_small = np.array([[10.0, 0, w / 2], [0, 10.0, h / 2], [0, 0, 1]])
    depth = rng.uniform(1.8, 2.2, (h, w))
    depth[rng.random((h, w)) < 0.2] = 0.0
    normals = np.array([0.0, 0.0, -1.0]) + rng.normal(0, 0.2, (h, w, 3))
    normals /= np.linalg.norm(normals, axis=-1, keepdims=True)
    rays = np.linalg.inv(K_small) @ np.stack([*np.meshgrid(np.arange(w) + 0.5, np.arange(h) + 0.5), np.ones((h, w))]
                                             ).reshape(3, -1)
    rays = rays.T.reshape(h, w, 3)
    expected = depth.copy()
    for y in range(h):
        for x in range(w):
            if depth[y, x] <= 0:
                continue
            found = []
            for qy in range(max(0, y - radius), min(h, y + radius + 1)):
                for qx in range(max(0, x - radius), min(w, x + radius + 1)):
                    if depth[qy, qx] <= 0:
                        continue
                    n = normals[qy, qx]
                    facing = n @ rays[y, x]
                    implied = (n @ (rays[qy, qx] * depth[qy, qx])) / facing
                    if abs(implied - depth[y, x]) <= agreement * depth[y, x]:
                        found.append(implied)
            expected[y, x] = np.mean(found)
    got = smooth_along_planes(depth.astype(np.float32), normals.astype(np.float32), K_small, radius, agreement, passes=1)
    np.testing.assert_allclose(got, expected, rtol=1e-5)
