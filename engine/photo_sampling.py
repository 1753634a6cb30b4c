"""Looking up surface points in the photos: the one home of vertex colouring and the texture bake.

Colouring a mesh (`engine/recon/colour.py`, both reconstruction methods) and baking a texture
(`engine/texture/bake.py`) are the same act: render the mesh's own depth map from a photo's camera
(`occlusion_depth`), keep the surface points that photo really sees (`visible_points`: in front,
inside the image, facing the camera, not hidden behind the rendered surface) and read their colour
(`sample_bilinear`). Points no photo sees are `UNSEEN_GREY`. The vertex evidence
(`engine/stereo/vertex_evidence.py`) projects with the same `points_in_view` and reads the stereo
depth maps instead of the photos. Pure numpy + OpenCV, below engine/recon
and engine/texture (it imports neither).

Pixel convention: pixel (row i, column j) covers u in [j, j + 1), v in [i, i + 1), the same as the
visibility test of view selection (0 <= u < W).
"""

from __future__ import annotations

import cv2
import numpy as np

from .geometry.cameras import camera_to_pixels, scale_intrinsics, world_to_camera
from .geometry.depth_render import NEAR_PLANE, render_depth
from .mesh_io import Mesh

UNSEEN_GREY = 0.5
MIN_COSINE = 0.1  # views at more than ~84 deg from the normal are too grazing to trust
DEPTH_LONG_SIDE = 160  # occlusion z-buffer resolution (long side, pixels)

REMAP_WIDTH = 4096  # cv2.remap takes maps of at most 32767 columns: sample points are laid out in rows


def sample_bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """(N, 3) float32 sRGB 0..255 at pixel coordinates u, v (pixel (0, 0) covers [0, 1)^2, its centre at
    0.5), edge-clamped; by cv2.remap, without a float copy of the (possibly 12-megapixel) photo."""
    n = len(u)
    if n == 0:
        return np.zeros((0, 3), np.float32)
    rows = -(-n // REMAP_WIDTH)
    map_x = np.zeros(rows * REMAP_WIDTH, np.float32)
    map_y = np.zeros(rows * REMAP_WIDTH, np.float32)
    map_x[:n], map_y[:n] = u - 0.5, v - 0.5  # cv2 puts integer coordinates at pixel centres
    out = cv2.remap(image, map_x.reshape(rows, REMAP_WIDTH), map_y.reshape(rows, REMAP_WIDTH),
                    interpolation=cv2.INTER_LINEAR, borderMode=cv2.BORDER_REPLICATE)
    return out.reshape(-1, 3)[:n].astype(np.float32)


def points_in_view(points: np.ndarray, K: np.ndarray, pose: np.ndarray, image_size: tuple[int, int]
                   ) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """The points a camera's image frames: (ids (M,) int64, u (M,), v (M,), z (M,)), in front of the
    camera (z > NEAR_PLANE) and inside the image of `image_size` = (w, h), K in its pixels. The one
    projection of vertex colours, the texture bake and the vertex evidence."""
    w, h = image_size
    cam = world_to_camera(points, pose)
    z = cam[:, 2]
    ids = np.flatnonzero(z > NEAR_PLANE)
    u, v = camera_to_pixels(cam[ids], K)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    return ids[inside], u[inside], v[inside], z[ids][inside]


def visible_points(
    points: np.ndarray, normals: np.ndarray, K: np.ndarray, pose: np.ndarray, image_size: tuple[int, int],
    depth: np.ndarray, tolerance: float,
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which surface points a camera sees: (ids (M,) int64, u (M,), v (M,), cosine (M,), z (M,)).

    points, normals (N, 3) world (normals point to free space); K in pixels of an image of
    `image_size` = (w, h); `depth` (dh, dw) the mesh's depth map from that camera, same field of view,
    any resolution. Seen = in front, inside the image, facing the camera (cos > MIN_COSINE) and no
    farther than `tolerance` + 2 % of the depth behind the rendered surface. The one occlusion test of
    vertex colours and the texture bake.
    """
    w, h = image_size
    dh, dw = depth.shape
    ids, u, v, z = points_in_view(points, K, pose, image_size)
    col = np.minimum(np.floor(u * (dw / w)).astype(np.int64), dw - 1)
    row = np.minimum(np.floor(v * (dh / h)).astype(np.int64), dh - 1)
    to_camera_dir = pose[:3, 3] - points[ids].astype(np.float64)
    to_camera_dir /= np.linalg.norm(to_camera_dir, axis=1, keepdims=True)
    cosine = np.einsum("nd,nd->n", normals[ids].astype(np.float64), to_camera_dir)
    unoccluded = z <= depth[row, col] + tolerance + 0.02 * z
    keep = unoccluded & (cosine > MIN_COSINE)
    return ids[keep], u[keep], v[keep], cosine[keep], z[keep]


def occlusion_depth(mesh: Mesh, K: np.ndarray, pose: np.ndarray, image_size: tuple[int, int],
                    long_side: int = DEPTH_LONG_SIDE) -> np.ndarray:
    """The mesh's depth map from a camera whose K is in pixels of `image_size` = (w, h), rendered at
    (at most) `long_side` pixels: the occlusion map of `visible_points`."""
    w, h = image_size
    scale = min(1.0, long_side / max(w, h))
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return render_depth(mesh.vertices, mesh.faces, scale_intrinsics(K, (w, h), size), pose, size)
