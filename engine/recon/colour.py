"""Occlusion-aware vertex colours from the photos.

A vertex takes colour only from views that actually see it: for each colour view the mesh itself is
rendered into a low-resolution depth map (a numpy z-buffer of points sampled on every triangle at
sub-pixel spacing), and a vertex is accepted when its depth is within a tolerance of that map and it
faces the camera. Accepted colours are averaged with weight cos(viewing angle), so grazing views,
which smear texture, count less. Vertices that no view sees are grey.

Pixel convention: pixel (row i, column j) covers u in [j, j + 1), v in [i, i + 1), the same as the
visibility test of view selection (0 <= u < W).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import cv2
import numpy as np

from ..capture.images import load_resized, resized_size
from ..geometry.cameras import camera_to_pixels, scale_intrinsics, world_to_camera
from ..geometry.depth_render import NEAR_PLANE, render_depth
from ..jobs import CancelToken, ProgressCallback, check, report
from ..mesh_io import Mesh

if TYPE_CHECKING:
    from .plan import ReconPlan
    from .settings import ReconSettings

UNSEEN_GREY = 0.5
MIN_COSINE = 0.1  # views at more than ~84 deg from the normal are too grazing to trust
DEPTH_LONG_SIDE = 160  # occlusion z-buffer resolution (long side, pixels)
COLOUR_LONG_SIDE = 320  # photos are sampled for colour at (at most) this size: vertices are 4 cm apart


@dataclass
class ColourView:
    image: np.ndarray  # (h, w, 3) uint8 RGB
    K: np.ndarray  # (3, 3) in pixels of `image`
    pose: np.ndarray  # (4, 4) camera-to-world, OpenCV axes


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
    cam = world_to_camera(points, pose)
    z = cam[:, 2]
    ids = np.flatnonzero(z > NEAR_PLANE)
    u, v = camera_to_pixels(cam[ids], K)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    col = np.minimum(np.floor(u * (dw / w)).astype(np.int64), dw - 1)
    row = np.minimum(np.floor(v * (dh / h)).astype(np.int64), dh - 1)
    ids, u, v, col, row = ids[inside], u[inside], v[inside], col[inside], row[inside]
    to_camera_dir = pose[:3, 3] - points[ids].astype(np.float64)
    to_camera_dir /= np.linalg.norm(to_camera_dir, axis=1, keepdims=True)
    cosine = np.einsum("nd,nd->n", normals[ids].astype(np.float64), to_camera_dir)
    unoccluded = z[ids] <= depth[row, col] + tolerance + 0.02 * z[ids]
    keep = unoccluded & (cosine > MIN_COSINE)
    return ids[keep], u[keep], v[keep], cosine[keep], z[ids][keep]


def visible_vertices(
    mesh: Mesh, view: ColourView, depth: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which vertices `view` sees: (ids (M,) int64, u (M,), v (M,), cosine (M,)); see `visible_points`.

    `depth` may have fewer pixels than `view.image` (same field of view); u, v are image pixels.
    """
    h, w = view.image.shape[:2]
    ids, u, v, cosine, _ = visible_points(mesh.vertices, mesh.normals, view.K, view.pose, (w, h), depth, tolerance)
    return ids, u, v, cosine


def occlusion_depth(mesh: Mesh, K: np.ndarray, pose: np.ndarray, image_size: tuple[int, int],
                    long_side: int = DEPTH_LONG_SIDE) -> np.ndarray:
    """The mesh's depth map from a camera whose K is in pixels of `image_size` = (w, h), rendered at
    (at most) `long_side` pixels: the occlusion map of `visible_points`."""
    w, h = image_size
    scale = min(1.0, long_side / max(w, h))
    size = (max(1, round(w * scale)), max(1, round(h * scale)))
    return render_depth(mesh.vertices, mesh.faces, scale_intrinsics(K, (w, h), size), pose, size)


def colour_vertices(mesh: Mesh, views: list[ColourView], tolerance: float) -> np.ndarray:
    """Per-vertex colours (V, 3) float32 0..1: cos-weighted mean over the views that see each vertex.

    tolerance: metres a vertex may lie behind the rendered depth and still count as seen (about two
    voxels: the z-buffer holds the nearest sample in a pixel, which may be a neighbouring triangle).
    """
    n = len(mesh.vertices)
    total = np.zeros((n, 3), dtype=np.float64)
    weight = np.zeros(n, dtype=np.float64)
    for view in views:
        h, w = view.image.shape[:2]
        # Occlusion is resolved at <= DEPTH_LONG_SIDE pixels: about 2 cm per pixel at 3 m, finer than
        # the tolerance, at a quarter of the rasterisation cost of a 320-pixel image.
        depth = occlusion_depth(mesh, view.K, view.pose, (w, h))
        ids, u, v, cosine = visible_vertices(mesh, view, depth, tolerance)
        total[ids] += cosine[:, None] * (sample_bilinear(view.image, u, v) / 255.0)
        weight[ids] += cosine
    colours = np.full((n, 3), UNSEEN_GREY, dtype=np.float64)
    seen = weight > 0
    colours[seen] = total[seen] / weight[seen, None]
    return colours.astype(np.float32)


def colour_mesh(
    mesh: Mesh,
    plan: "ReconPlan",
    settings: "ReconSettings",
    progress: Optional[ProgressCallback],
    cancel: Optional[CancelToken],
) -> np.ndarray:
    """Vertex colours (V, 3) float32 from up to `settings.colour_views` evenly spaced keyframes."""
    if not settings.colour or settings.colour_views < 1:
        return np.full((len(mesh.vertices), 3), 0.5, np.float32)
    count = min(settings.colour_views, len(plan.keyframes))
    picks = np.unique(np.round(np.linspace(0, len(plan.keyframes) - 1, count)).astype(np.int64))
    views = []
    for done, k in enumerate(picks):
        check(cancel)
        report(progress, "colour", done, len(picks) + 1)
        frame = plan.keyframes[k]
        size = resized_size(frame.width, frame.height, min(COLOUR_LONG_SIDE, max(frame.width, frame.height)))
        K = scale_intrinsics(plan.Ks[k], (frame.width, frame.height), size)
        views.append(ColourView(load_resized(frame, size), K, plan.poses[k]))
    colours = colour_vertices(mesh, views, tolerance=2 * settings.voxel_size)
    report(progress, "colour", len(picks) + 1, len(picks) + 1)
    return colours
