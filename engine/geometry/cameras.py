"""Pinhole camera geometry: the one place where poses, intrinsics and projections are written.

Conventions (docs/architecture: "Conventions"): world Z up, metres; a pose is camera-to-world (4, 4)
float64 with OpenCV camera axes (x right, y down, z forward); K (3, 3) is in pixels of the image it
belongs to, pixel (row i, column j) covering u in [j, j + 1), v in [i, i + 1).

numpy functions serve capture, recon, tsdf, data and eval; `project_points_torch` and
`intrinsics_at_stride` serve the network and its losses, where tensors stay on the GPU.
"""

from __future__ import annotations

from typing import TYPE_CHECKING, Sequence, TypeVar

import numpy as np

from ..errors import PoseError

if TYPE_CHECKING:  # torch is imported only by the tensor functions: planning and capture stay numpy-only
    import torch

# Projections of points this close to the camera plane divide by this instead (finite, far outside
# any image); callers test z > 0 before trusting u, v.
MIN_ABS_DEPTH = 1e-9

ArrayOrTensor = TypeVar("ArrayOrTensor", np.ndarray, "torch.Tensor")


# ---------------------------------------------------------------------------------------- poses


def look_along(eye: Sequence[float], forward: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0),
               roll: float = 0.0) -> np.ndarray:
    """Camera-to-world (4, 4) at `eye` looking along `forward`: image x level (perpendicular to `up`),
    image y pointing away from `up`, then turned by `roll` radians about the optical axis.

    A camera looking straight along `up` has no level direction; it gets image x = world +X.
    """
    z = np.asarray(forward, np.float64) / np.linalg.norm(forward)
    x = np.cross(z, np.asarray(up, np.float64))
    x = x / np.linalg.norm(x) if np.linalg.norm(x) > 1e-9 else np.array([1.0, 0.0, 0.0])
    y = np.cross(z, x)  # points down in the image when x is level
    if roll:
        c, s = np.cos(roll), np.sin(roll)
        x, y = c * x + s * y, -s * x + c * y
    pose = np.eye(4)
    pose[:3, 0], pose[:3, 1], pose[:3, 2], pose[:3, 3] = x, y, z, eye
    return pose


def look_at(eye: Sequence[float], target: Sequence[float], up: Sequence[float] = (0.0, 0.0, 1.0)) -> np.ndarray:
    """Camera-to-world (4, 4), OpenCV axes, at `eye` with its optical axis through `target`, no roll."""
    eye = np.asarray(eye, np.float64)
    return look_along(eye, np.asarray(target, np.float64) - eye, up)


# ----------------------------------------------------------------------------------- projection


def pixels_to_world(u: np.ndarray, v: np.ndarray, depth: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray
                    ) -> np.ndarray:
    """(N, 3) world points of pixels at columns u, rows v (each (N,), integers: their centres at +0.5)
    with planar depths `depth` (N,) metres, through a pinhole K (3, 3) at `cam_to_world` (4, 4)."""
    z = np.asarray(depth, np.float64)
    rays = np.linalg.inv(np.asarray(K, np.float64)) @ np.stack([np.asarray(u) + 0.5, np.asarray(v) + 0.5, np.ones_like(z)])
    pose = np.asarray(cam_to_world, np.float64)
    return (pose[:3, :3] @ (rays * z) + pose[:3, 3:4]).T


def world_to_camera(points: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """World points (M, 3) -> camera coordinates: (M, 3) for one pose (4, 4), (V, M, 3) for poses (V, 4, 4)."""
    points = np.asarray(points, np.float64)
    w2c = np.linalg.inv(np.asarray(cam_to_world, np.float64))
    if w2c.ndim == 2:  # one camera: a BLAS matmul, 3x faster than einsum on a big mesh's vertices
        return points @ w2c[:3, :3].T + w2c[:3, 3]
    return np.einsum("...ij,mj->...mi", w2c[..., :3, :3], points) + w2c[..., None, :3, 3]


def camera_to_pixels(cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera points (..., M, 3) -> pixel coordinates u, v (..., M) through a pinhole K (3, 3) or
    (..., 3, 3): [[fx, skew, cx], [0, fy, cy], [0, 0, 1]]. Points with |z| < MIN_ABS_DEPTH get finite
    nonsense: test z > 0 first."""
    K = np.asarray(K, np.float64)
    x, y, z = cam[..., 0], cam[..., 1], cam[..., 2]
    z_safe = np.where(np.abs(z) < MIN_ABS_DEPTH, MIN_ABS_DEPTH, z)

    def k(i: int, j: int) -> np.ndarray:  # K entry, broadcastable against (..., M)
        return K[..., i, j, None]

    # Written out instead of K @ cam: 2-3x faster on the millions of points of a depth render.
    return (k(0, 0) * x + k(0, 1) * y) / z_safe + k(0, 2), k(1, 1) * y / z_safe + k(1, 2)


def project_points(points: np.ndarray, K: np.ndarray, cam_to_world: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """World points (M, 3) -> u, v, z in each camera, view-major: (V, M) for K (V, 3, 3) and
    cam_to_world (V, 4, 4); (M,) for a single K (3, 3) and pose (4, 4). z is the camera depth
    (<= 0 behind the camera)."""
    cam = world_to_camera(points, cam_to_world)
    u, v = camera_to_pixels(cam, K)
    return u, v, cam[..., 2]


def projection_matrix(K: np.ndarray, cam_to_world: np.ndarray) -> np.ndarray:
    """P (3, 4) = K [R^T | -R^T t]: P @ (x, y, z, 1) = (z_cam u, z_cam v, z_cam). For callers that
    evaluate it separably on a voxel grid (TSDF fusion)."""
    return np.asarray(K, np.float64) @ np.linalg.inv(np.asarray(cam_to_world, np.float64))[:3]


def project_points_torch(points: "torch.Tensor", K: "torch.Tensor", cam_to_world: "torch.Tensor"
                         ) -> tuple["torch.Tensor", "torch.Tensor", "torch.Tensor"]:
    """`project_points` for tensors, voxel-major as the network's inputs: points (M, 3), K (V, 3, 3),
    cam_to_world (V, 4, 4) -> u, v, z each (M, V), in the points' dtype and device.

    The pose is inverted in float64: poses metres from the origin lose millimetres in a float32 inverse.
    """
    import torch  # defers torch: heavy

    dtype = points.dtype
    w2c = torch.linalg.inv(cam_to_world.to(torch.float64)).to(dtype)
    cam = torch.einsum("vij,mj->mvi", w2c[:, :3, :3], points) + w2c[None, :, :3, 3]
    z = cam[..., 2]
    z_safe = torch.where(z.abs() < MIN_ABS_DEPTH, torch.full_like(z, MIN_ABS_DEPTH), z)
    uvw = torch.einsum("vij,mvj->mvi", K.to(dtype), cam)
    return uvw[..., 0] / z_safe, uvw[..., 1] / z_safe, z


# ----------------------------------------------------------------------------------- intrinsics


def scale_intrinsics(K: ArrayOrTensor, from_size: tuple[int, int], to_size: tuple[int, int]) -> ArrayOrTensor:
    """K (..., 3, 3) for an image resized from (w, h) to (w', h'): row 0 times w'/w, row 1 times h'/h
    (no half-pixel correction, like the official code). numpy in, float64 numpy out; a tensor stays a tensor."""
    sx, sy = to_size[0] / from_size[0], to_size[1] / from_size[1]
    K = _writable_copy(K)
    K[..., 0, :] = K[..., 0, :] * sx
    K[..., 1, :] = K[..., 1, :] * sy
    return K


def intrinsics_at_stride(K: ArrayOrTensor, stride: int) -> ArrayOrTensor:
    """K (..., 3, 3) of a feature map at 1/`stride` of the image, in the network's convention: feature
    pixel (u, v) is image pixel (stride u, stride v) (rows 0-1 divided, no half-pixel shift), whatever
    the map's rounded size."""
    K = _writable_copy(K)
    K[..., :2, :] = K[..., :2, :] / stride
    return K


def _writable_copy(K: ArrayOrTensor) -> ArrayOrTensor:
    """A tensor is cloned (same dtype and device); anything else becomes a float64 numpy copy."""
    return K.clone() if _is_tensor(K) else np.array(K, dtype=np.float64)


def _is_tensor(x: object) -> bool:
    return type(x).__module__.startswith("torch")


# -------------------------------------------------------------------------------------- frustum


def frustum_corners(K: np.ndarray, cam_to_world: np.ndarray, width: int, height: int, depth: float) -> np.ndarray:
    """(4, 3) world positions of the image corners (u, v) = (0, 0), (0, H), (W, 0), (W, H) at planar
    depth `depth` (pixel-edge coordinates, like NeuralRecon's `get_view_frustum`).

    K (3, 3) pixels (skew allowed); cam_to_world (4, 4) OpenCV axes. Callers that need the whole
    frustum add the camera centre `cam_to_world[:3, 3]`.
    """
    u = np.array([0.0, 0.0, width, width])
    v = np.array([0.0, height, 0.0, height])
    y = (v - K[1, 2]) * depth / K[1, 1]
    x = (u - K[0, 2] - K[0, 1] * (v - K[1, 2]) / K[1, 1]) * depth / K[0, 0]
    cam = np.stack([x, y, np.full(4, float(depth))], axis=1)
    return cam @ np.asarray(cam_to_world, np.float64)[:3, :3].T + cam_to_world[:3, 3]


def mean_up_direction(cam_to_world: np.ndarray) -> np.ndarray:
    """(N, 4, 4) camera-to-world (OpenCV axes) -> (3,) unit mean of the cameras' up vectors (-y)."""
    ups = -cam_to_world[:, :3, 1]
    mean = ups.mean(axis=0)
    norm = np.linalg.norm(mean)
    if norm < 1e-6:
        raise PoseError("cannot find 'up': the cameras' up directions cancel out (cameras pointing every way)")
    return mean / norm


def rotation_taking(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector a onto unit vector b (Rodrigues).

    Smallest, so the heading (yaw) of the SfM world is kept: the scene does not spin around Z.
    """
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-12:
        # Opposite vectors: any half-turn about an axis perpendicular to a will do.
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def turned_clockwise(K: np.ndarray, cam_to_world: np.ndarray, size: tuple[int, int],
                     quarter_turns: int) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """The camera of an image (width, height) = `size` turned `quarter_turns` x 90 deg clockwise, as
    `numpy.rot90(image, -quarter_turns)` turns it: (K (3, 3), camera-to-world (4, 4), new (width, height)).

    One clockwise turn moves pixel (u, v) to (height - v, u), so the new camera's x axis is the old -y
    and its y axis the old x: fx' = fy, cx' = height - cy, fy' = fx, cy' = cx. The world point seen at a
    pixel is the same before and after, so depth maps turn with their photos and nothing else changes.
    """
    K, pose = np.asarray(K, np.float64).copy(), np.asarray(cam_to_world, np.float64).copy()
    width, height = size
    # new camera axes in old camera coordinates: x' = -y, y' = x, z' = z
    one_turn = np.array([[0.0, 1.0, 0.0], [-1.0, 0.0, 0.0], [0.0, 0.0, 1.0]])
    for _ in range(quarter_turns % 4):
        K = np.array([[K[1, 1], 0.0, height - K[1, 2]], [0.0, K[0, 0], K[0, 2]], [0.0, 0.0, 1.0]])
        pose[:3, :3] = pose[:3, :3] @ one_turn
        width, height = height, width
    return K, pose, (width, height)


def upright_quarter_turns(cam_to_world: np.ndarray, up: Sequence[float] = (0.0, 0.0, 1.0)) -> int:
    """How many clockwise quarter turns (0-3) make the images of cameras (N, 4, 4) upright: world `up`
    pointing up the image (-y) on average. A handheld capture keeps one orientation throughout, so one
    number serves every frame."""
    up_in_camera = np.einsum("nji,j->ni", np.asarray(cam_to_world, np.float64)[:, :3, :3], np.asarray(up, np.float64))
    x, y = up_in_camera[:, 0].mean(), up_in_camera[:, 1].mean()
    # up after k clockwise turns, in the turned image: (x, y) -> (-y, x) per turn; upright when its y is least
    ys = [y, x, -y, -x]
    return int(np.argmin(ys))
