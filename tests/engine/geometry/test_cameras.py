"""Camera geometry (engine.geometry.cameras) against hand-computed pinhole numbers."""

from __future__ import annotations

import numpy as np
import torch

from engine.geometry.cameras import (frustum_corners, intrinsics_at_stride, look_along, look_at, pixels_to_world,
                                     project_points, project_points_torch, projection_matrix, scale_intrinsics)

K = np.array([[100.0, 0.0, 64.0], [0.0, 90.0, 48.0], [0.0, 0.0, 1.0]])


def test_look_at_puts_the_target_on_the_optical_axis_with_a_level_image():
    eye, target = np.array([1.0, 2.0, 1.5]), np.array([3.0, -1.0, 0.5])
    pose = look_at(eye, target)
    R = pose[:3, :3]
    assert np.allclose(R.T @ R, np.eye(3)) and np.isclose(np.linalg.det(R), 1.0)
    assert np.allclose(pose[:3, 3], eye)
    assert np.allclose(R[:, 2], (target - eye) / np.linalg.norm(target - eye))
    assert abs(R[2, 0]) < 1e-12  # image x is horizontal
    assert R[2, 1] < 0  # image y (down) points away from world up
    u, v, z = project_points(target[None], K, pose)
    assert np.allclose([u[0], v[0]], [64.0, 48.0]) and np.isclose(z[0], np.linalg.norm(target - eye))
    assert np.allclose(look_along(eye, target - eye), pose)


def test_look_along_roll_turns_the_image_about_the_optical_axis():
    level = look_along([0, 0, 0], [1.0, 0, 0])
    rolled = look_along([0, 0, 0], [1.0, 0, 0], roll=np.pi / 2)
    assert np.allclose(rolled[:3, 2], level[:3, 2])
    assert np.allclose(rolled[:3, 0], level[:3, 1])  # x turned onto the old y


def test_project_points_is_view_major_and_matches_a_pinhole_by_hand():
    poses = np.stack([np.eye(4), look_at([0, 0, 0], [1.0, 0, 0])])
    point = np.array([[0.5, -0.25, 2.0], [2.0, 0.2, 0.1]])
    u, v, z = project_points(point, np.stack([K, K]), poses)
    assert u.shape == (2, 2)
    assert np.isclose(u[0, 0], 100 * 0.5 / 2 + 64) and np.isclose(v[0, 0], 90 * -0.25 / 2 + 48)
    # the second camera looks along +x: camera x = -world y, camera y = -world z, depth = world x
    assert np.isclose(z[1, 1], 2.0) and np.isclose(u[1, 1], 100 * -0.2 / 2 + 64) and np.isclose(v[1, 1], 90 * -0.1 / 2 + 48)
    P = projection_matrix(K, poses[1])
    uvw = P @ np.append(point[1], 1.0)
    assert np.allclose(uvw[:2] / uvw[2], [u[1, 1], v[1, 1]])
    ut, vt, zt = project_points_torch(torch.from_numpy(point), torch.from_numpy(np.stack([K, K])), torch.from_numpy(poses))
    assert np.allclose(ut.numpy().T, u) and np.allclose(vt.numpy().T, v) and np.allclose(zt.numpy().T, z)


def test_frustum_corners_project_back_to_the_image_corners():
    pose = look_at([0.3, -0.2, 1.4], [2.0, 1.0, 1.0])
    skewed = K.copy()
    skewed[0, 1] = 3.0
    for intrinsics in (K, skewed):
        corners = frustum_corners(intrinsics, pose, 128, 96, 2.5)
        u, v, z = project_points(corners, intrinsics, pose)
        assert np.allclose(u, [0, 0, 128, 128]) and np.allclose(v, [0, 96, 0, 96]) and np.allclose(z, 2.5)


def test_scale_intrinsics_and_stride_keep_numpy_and_tensors():
    half = scale_intrinsics(K, (128, 96), (64, 32))
    assert np.allclose(half, [[50, 0, 32], [0, 30, 16], [0, 0, 1]]) and np.allclose(K[0, 0], 100.0)
    batched = scale_intrinsics(torch.from_numpy(np.stack([K, K])).float(), (128, 96), (64, 32))
    assert isinstance(batched, torch.Tensor) and batched.dtype == torch.float32
    assert np.allclose(batched.numpy(), half)
    at4 = intrinsics_at_stride(torch.from_numpy(K), 4)
    assert np.allclose(at4.numpy(), [[25, 0, 16], [0, 22.5, 12], [0, 0, 1]])


def test_pixels_lifted_to_world_project_back_to_their_centres():
    K = np.array([[500.0, 0, 320], [0, 480.0, 240], [0, 0, 1]])
    pose = look_at(np.array([1.0, -2.0, 1.5]), np.array([0.5, 3.0, 0.8]))
    u, v, depth = np.array([0, 17, 639]), np.array([0, 200, 479]), np.array([0.5, 2.0, 7.25])
    points = pixels_to_world(u, v, depth, K, pose)
    pu, pv, z = project_points(points, K, pose)
    assert np.allclose(pu, u + 0.5) and np.allclose(pv, v + 0.5) and np.allclose(z, depth)
