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

import numpy as np

from ..mesh_io import Mesh

UNSEEN_GREY = 0.5
NEAR_PLANE = 0.05  # metres; triangles closer than this to a camera are not rendered
MIN_COSINE = 0.1  # views at more than ~84 deg from the normal are too grazing to trust
MAX_EDGE_SAMPLES = 64  # caps the samples of a huge (very close) triangle to 65 x 66 / 2
DEPTH_LONG_SIDE = 160  # occlusion z-buffer resolution (long side, pixels)
SAMPLES_PER_CALL = 4_000_000  # bounds the (triangles, samples, 3) buffer to ~100 MB


@dataclass
class ColourView:
    image: np.ndarray  # (h, w, 3) uint8 RGB
    K: np.ndarray  # (3, 3) in pixels of `image`
    pose: np.ndarray  # (4, 4) camera-to-world, OpenCV axes


def to_camera(points: np.ndarray, pose: np.ndarray) -> np.ndarray:
    """World points (N, 3) -> camera coordinates (N, 3) for a camera-to-world pose (4, 4)."""
    return (np.asarray(points, dtype=np.float64) - pose[:3, 3]) @ pose[:3, :3]


def _project(cam: np.ndarray, K: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """Camera points (..., 3) with z > 0 -> pixel coordinates u, v (...)."""
    z = cam[..., 2]
    return (K[0, 0] * cam[..., 0] + K[0, 1] * cam[..., 1]) / z + K[0, 2], K[1, 1] * cam[..., 1] / z + K[1, 2]


def render_depth(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, pose: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Planar depth (h, w) float32 of the mesh seen from one camera; inf where nothing is hit.

    vertices (V, 3) world; faces (F, 3); K (3, 3); pose (4, 4) camera-to-world; size = (w, h).
    Each triangle is sampled on a barycentric lattice fine enough that neighbouring samples are at
    most half a pixel apart, so it covers every pixel it overlaps; samples are exact points of the
    3D triangle, so depths are perspective-correct. Triangles crossing the near plane are skipped.
    """
    w, h = size
    depth = np.full(h * w, np.inf, dtype=np.float64)
    cam = to_camera(vertices, pose)
    in_front = cam[:, 2] > NEAR_PLANE
    tris = faces[in_front[faces].all(axis=1)]
    if len(tris) == 0:
        return depth.reshape(h, w).astype(np.float32)
    # Vertices behind the camera get a dummy depth of 1; only triangles fully in front are used.
    u, v = _project(np.where(in_front[:, None], cam, [0.0, 0.0, 1.0]), K)
    tu, tv = u[tris], v[tris]  # (T, 3)
    on_screen = (tu.max(1) >= 0) & (tu.min(1) < w) & (tv.max(1) >= 0) & (tv.min(1) < h)
    tris, tu, tv = tris[on_screen], tu[on_screen], tv[on_screen]
    edge = np.max(np.hypot(tu - np.roll(tu, 1, axis=1), tv - np.roll(tv, 1, axis=1)), axis=1)
    steps = np.clip(np.ceil(2.0 * edge), 1, MAX_EDGE_SAMPLES).astype(np.int64)
    for n in np.unique(steps):
        group = tris[steps == n]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        w1, w2 = i[keep] / n, j[keep] / n
        bary = np.stack([1.0 - w1 - w2, w1, w2], axis=1)  # (S, 3)
        per_call = max(1, SAMPLES_PER_CALL // len(bary))
        for a in range(0, len(group), per_call):
            corners = cam[group[a:a + per_call]]  # (t, 3, 3)
            # Three broadcast multiply-adds: several times faster than einsum for these shapes.
            points = (bary[None, :, 0, None] * corners[:, None, 0] + bary[None, :, 1, None] * corners[:, None, 1]
                      + bary[None, :, 2, None] * corners[:, None, 2]).reshape(-1, 3)
            pu, pv = _project(points, K)
            col, row = np.floor(pu).astype(np.int64), np.floor(pv).astype(np.int64)
            inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
            np.minimum.at(depth, row[inside] * w + col[inside], points[inside, 2])
    return depth.reshape(h, w).astype(np.float32)


def _bilinear(image: np.ndarray, u: np.ndarray, v: np.ndarray) -> np.ndarray:
    """RGB (N, 3) float 0..1 at pixel coordinates u, v (pixel centres at +0.5), edge-clamped."""
    h, w = image.shape[:2]
    x = np.clip(u - 0.5, 0, w - 1)
    y = np.clip(v - 0.5, 0, h - 1)
    x0, y0 = np.floor(x).astype(np.int64), np.floor(y).astype(np.int64)
    x1, y1 = np.minimum(x0 + 1, w - 1), np.minimum(y0 + 1, h - 1)
    fx, fy = (x - x0)[:, None], (y - y0)[:, None]
    img = image.astype(np.float32) / 255.0
    top = img[y0, x0] * (1 - fx) + img[y0, x1] * fx
    bottom = img[y1, x0] * (1 - fx) + img[y1, x1] * fx
    return top * (1 - fy) + bottom * fy


def visible_vertices(
    mesh: Mesh, view: ColourView, depth: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which vertices `view` sees: (ids (M,) int64, u (M,), v (M,), cosine (M,)).

    Seen = in front, inside the image, facing the camera (cos > MIN_COSINE, needs normals pointing to
    free space) and no farther than `tolerance` + 2 % of the depth behind the rendered surface.
    `depth` may have fewer pixels than `view.image` (same field of view); u, v are image pixels.
    """
    h, w = view.image.shape[:2]
    dh, dw = depth.shape
    cam = to_camera(mesh.vertices, view.pose)
    z = cam[:, 2]
    ids = np.flatnonzero(z > NEAR_PLANE)
    u, v = _project(cam[ids], view.K)
    inside = (u >= 0) & (u < w) & (v >= 0) & (v < h)
    col = np.minimum(np.floor(u * (dw / w)).astype(np.int64), dw - 1)
    row = np.minimum(np.floor(v * (dh / h)).astype(np.int64), dh - 1)
    ids, u, v, col, row = ids[inside], u[inside], v[inside], col[inside], row[inside]
    to_camera_dir = view.pose[:3, 3] - mesh.vertices[ids].astype(np.float64)
    to_camera_dir /= np.linalg.norm(to_camera_dir, axis=1, keepdims=True)
    cosine = np.einsum("nd,nd->n", mesh.normals[ids].astype(np.float64), to_camera_dir)
    unoccluded = z[ids] <= depth[row, col] + tolerance + 0.02 * z[ids]
    keep = unoccluded & (cosine > MIN_COSINE)
    return ids[keep], u[keep], v[keep], cosine[keep]


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
        scale = min(1.0, DEPTH_LONG_SIDE / max(w, h))
        size = (max(1, round(w * scale)), max(1, round(h * scale)))
        K_depth = np.diag([size[0] / w, size[1] / h, 1.0]) @ view.K
        depth = render_depth(mesh.vertices, mesh.faces, K_depth, view.pose, size)
        ids, u, v, cosine = visible_vertices(mesh, view, depth, tolerance)
        total[ids] += cosine[:, None] * _bilinear(view.image, u, v)
        weight[ids] += cosine
    colours = np.full((n, 3), UNSEEN_GREY, dtype=np.float64)
    seen = weight > 0
    colours[seen] = total[seen] / weight[seen, None]
    return colours.astype(np.float32)
