"""Back-projection and view-direction encoding against hand-computed cameras."""

from __future__ import annotations

import math

import pytest
import torch

from engine.model.backprojection import project_to_feature_maps, sample_features
from engine.geometry.cameras import intrinsics_at_stride
from engine.model.view_encoding import ENCODING_CHANNELS, encode_directions, ray_directions

H, W = 48, 64
K = torch.tensor([[50.0, 0.0, 31.0], [0.0, 55.0, 23.0], [0.0, 0.0, 1.0]])


pytestmark = pytest.mark.usefixtures("single_torch_thread")


def rotation_z(angle: float) -> torch.Tensor:
    c, s = math.cos(angle), math.sin(angle)
    return torch.tensor([[c, -s, 0.0], [s, c, 0.0], [0.0, 0.0, 1.0]], dtype=torch.float64)


def camera_pose() -> torch.Tensor:
    """A camera at (1, -2, 1.5), looking along world +Y (OpenCV axes: x right, y down, z forward),
    then yawed by 20 degrees so no axis is trivially aligned."""
    look_y = torch.tensor([[1.0, 0.0, 0.0], [0.0, 0.0, 1.0], [0.0, -1.0, 0.0]], dtype=torch.float64)
    pose = torch.eye(4, dtype=torch.float64)
    pose[:3, :3] = rotation_z(math.radians(20)) @ look_y
    pose[:3, 3] = torch.tensor([1.0, -2.0, 1.5], dtype=torch.float64)
    return pose


def world_point(pose: torch.Tensor, image_uv: tuple[float, float], depth: float) -> torch.Tensor:
    """The world point seen at image pixel (u, v) at camera depth `depth`."""
    u, v = image_uv
    cam = torch.tensor([(u - K[0, 2]) / K[0, 0] * depth, (v - K[1, 2]) / K[1, 1] * depth, depth], dtype=torch.float64)
    return (pose[:3, :3] @ cam + pose[:3, 3]).float()


def index_feature_map(h: int, w: int) -> torch.Tensor:
    """(1, 3, h, w): channel 0 = column u, channel 1 = row v, channel 2 = linear pixel index v*w + u."""
    v, u = torch.meshgrid(torch.arange(h, dtype=torch.float32), torch.arange(w, dtype=torch.float32), indexing="ij")
    return torch.stack([u, v, v * w + u])[None]


def test_back_projecting_a_known_point_samples_the_expected_feature_pixel():
    pose = camera_pose()
    stride = 4
    h, w = H // stride, W // stride
    feats = index_feature_map(h, w)
    # Feature pixel (5, 7) is image pixel (20, 28) (no half-pixel shift); (9.25, 3.5) is off-grid.
    targets = [(5.0, 7.0), (9.25, 3.5)]
    points = torch.stack([world_point(pose, (u * stride, v * stride), depth) for (u, v), depth in zip(targets, (2.0, 3.7))])

    projection = project_to_feature_maps(points, K[None], pose[None], stride, (h, w))
    sampled = sample_features(feats, projection.grid)  # (M, V=1, 3)

    for i, (u, v) in enumerate(targets):
        torch.testing.assert_close(sampled[i, 0], torch.tensor([u, v, v * w + u]), atol=1e-3, rtol=0)
        torch.testing.assert_close(projection.pixels[i, 0], torch.tensor([u * stride, v * stride]), atol=1e-3, rtol=0)
    torch.testing.assert_close(projection.depth[:, 0], torch.tensor([2.0, 3.7]), atol=1e-5, rtol=0)
    assert projection.valid.all()


def test_projection_validity_inside_image_and_in_front_only():
    pose = camera_pose()
    stride = 8
    h, w = H // stride, W // stride
    # The valid range ends at the first/last pixel centres (align_corners=True), not the image border.
    first = world_point(pose, (0.2, 0.2), 2.0)
    last = world_point(pose, ((w - 1) * stride - 0.2, (h - 1) * stride - 0.2), 2.0)
    outside = world_point(pose, ((w - 1) * stride + 1.0, 10.0), 2.0)
    behind = world_point(pose, (20.0, 20.0), -2.0)  # projects inside the image, but behind the camera
    projection = project_to_feature_maps(torch.stack([first, last, outside, behind]), K[None], pose[None], stride, (h, w))
    assert projection.valid[:, 0].tolist() == [True, True, False, False]
    assert projection.depth[3, 0] < 0


def test_intrinsics_scaled_without_half_pixel_shift():
    K_s = intrinsics_at_stride(K, 16)
    torch.testing.assert_close(K_s[0], K[0] / 16)
    torch.testing.assert_close(K_s[1], K[1] / 16)
    torch.testing.assert_close(K_s[2], K[2])


def test_ray_through_the_principal_point_is_the_camera_axis():
    pose = camera_pose()
    stride = 1
    K_int = K.clone()
    K_int[0, 2], K_int[1, 2] = 31.0, 23.0  # integer principal point -> a pixel centre
    rays = ray_directions(intrinsics_at_stride(K_int, stride)[None], pose[None].float(), H, W)
    assert rays.shape == (1, 3, H, W)
    torch.testing.assert_close(rays[0, :, 23, 31], pose[:3, 2].float(), atol=1e-6, rtol=0)
    torch.testing.assert_close(rays.norm(dim=1), torch.ones(1, H, W), atol=1e-6, rtol=0)
    # Pixel (u, v) looks along R @ normalize(((u - cx) / fx, (v - cy) / fy, 1)).
    expected = pose[:3, :3].float() @ torch.tensor([(60 - 31) / 50.0, (2 - 23) / 55.0, 1.0])
    torch.testing.assert_close(rays[0, :, 2, 60], expected / expected.norm(), atol=1e-6, rtol=0)


def test_direction_encoding_layout():
    d = torch.nn.functional.normalize(torch.randn(2, 3, 4, 5), dim=1)
    enc = encode_directions(d)
    assert enc.shape == (2, ENCODING_CHANNELS, 4, 5) and ENCODING_CHANNELS == 27
    torch.testing.assert_close(enc[:, 0:3], d)
    for i in range(4):
        torch.testing.assert_close(enc[:, 3 + 6 * i : 6 + 6 * i], torch.sin(math.pi * 2**i * d))
        torch.testing.assert_close(enc[:, 6 + 6 * i : 9 + 6 * i], torch.cos(math.pi * 2**i * d))
