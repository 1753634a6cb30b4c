"""Depth maps of a triangle mesh seen from a posed camera (a numpy z-buffer, no GPU, no Blender).

Used by vertex colouring (occlusion), the depth metrics of `engine.eval`, the held-out evaluation
picture and the capture-view picture script; `shade` turns a depth map into a grey picture. The
point samples (`lattice_samples`) are shared with the colour renders of `engine.eval.view_render`.
Pixel convention: pixel (row i, column j) covers u in [j, j + 1), v in [i, i + 1) (engine/geometry/cameras.py).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Iterator

import numpy as np

from .cameras import camera_to_pixels, world_to_camera

NEAR_PLANE = 0.05  # metres; triangles closer than this to a camera are not rendered
MAX_EDGE_SAMPLES = 64  # caps the samples of a huge (very close) triangle to 65 x 66 / 2
SAMPLES_PER_CALL = 4_000_000  # bounds the (triangles, samples, 3) buffer to ~100 MB


@dataclass
class LatticeChunk:
    """Samples of some triangles on their barycentric lattices, in one camera.

    faces (t,) int64: the triangles (indices into the mesh's faces); samples: lattice points per
    triangle (S), sample k of triangle i being row i * S + k below; points (t * S, 3) float64 camera
    coordinates; flat (t * S,) int64 pixel index row * w + col; inside (t * S,) bool: on the image.
    """

    faces: np.ndarray
    samples: int
    points: np.ndarray
    flat: np.ndarray
    inside: np.ndarray


def lattice_samples(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, pose: np.ndarray, size: tuple[int, int],
                    max_edge_samples: int = MAX_EDGE_SAMPLES) -> Iterator[LatticeChunk]:
    """The point samples a z-buffer of the mesh is built from, a chunk at a time (the one home of the
    sampling `render_depth` and `engine.eval.view_render.render_surface` share).

    vertices (V, 3) world; faces (F, 3); K (3, 3); pose (4, 4) camera-to-world; size = (w, h).
    Each triangle is sampled on a barycentric lattice fine enough that neighbouring samples are at
    most half a pixel apart (at most `max_edge_samples` steps per edge), so it covers every pixel it
    overlaps; samples are exact points of the 3D triangle, so depths are perspective-correct.
    Triangles crossing the near plane are skipped, and so are triangles wholly off the image.
    """
    w, h = size
    faces = np.asarray(faces)
    cam = world_to_camera(vertices, pose)
    in_front = cam[:, 2] > NEAR_PLANE
    # Vertices behind the camera get a dummy depth of 1; only triangles fully in front are used.
    u, v = camera_to_pixels(np.where(in_front[:, None], cam, [0.0, 0.0, 1.0]), K)
    # Per-vertex outcodes (left, right, above, below the image; behind the near plane): a triangle
    # whose three vertices share a side bit is off the image (its box misses it), one with any
    # vertex behind is skipped. Bytes per vertex instead of coordinates per face corner: a big
    # space's mesh is mostly outside any one view.
    code = ((u < 0) | ((u >= w) << 1) | ((v < 0) << 2) | ((v >= h) << 3) | (~in_front << 4)).astype(np.uint8)
    c0, c1, c2 = code[faces[:, 0]], code[faces[:, 1]], code[faces[:, 2]]
    face_ids = np.flatnonzero(((c0 & c1 & c2) == 0) & (((c0 | c1 | c2) & 16) == 0))
    if len(face_ids) == 0:
        return
    tris = faces[face_ids]
    tu, tv = u[tris], v[tris]  # (T, 3)
    edge = np.max(np.hypot(tu - np.roll(tu, 1, axis=1), tv - np.roll(tv, 1, axis=1)), axis=1)
    steps = np.clip(np.ceil(2.0 * edge), 1, max_edge_samples).astype(np.int64)
    for n in np.unique(steps):
        chosen = steps == n
        group, group_ids = tris[chosen], face_ids[chosen]
        i, j = np.meshgrid(np.arange(n + 1), np.arange(n + 1), indexing="ij")
        keep = i + j <= n
        w1, w2 = i[keep] / n, j[keep] / n
        bary = np.stack([1.0 - w1 - w2, w1, w2], axis=1)  # (S, 3)
        per_call = max(1, SAMPLES_PER_CALL // len(bary))
        for a in range(0, len(group), per_call):
            corners = cam[group[a:a + per_call]]  # (t, 3, 3)
            # (S, 3) @ (t, 3, 3) -> (t, S, 3): a batched matmul, 4x faster than broadcast multiply-adds.
            points = np.matmul(bary, corners).reshape(-1, 3)
            pu, pv = camera_to_pixels(points, K)
            col, row = np.floor(pu).astype(np.int64), np.floor(pv).astype(np.int64)
            inside = (col >= 0) & (col < w) & (row >= 0) & (row < h)
            yield LatticeChunk(group_ids[a:a + per_call], len(bary), points, row * w + col, inside)


def render_depth(vertices: np.ndarray, faces: np.ndarray, K: np.ndarray, pose: np.ndarray, size: tuple[int, int]) -> np.ndarray:
    """Planar depth (h, w) float32 of the mesh seen from one camera; inf where nothing is hit.

    vertices (V, 3) world; faces (F, 3); K (3, 3); pose (4, 4) camera-to-world; size = (w, h).
    Each pixel holds the nearest of the `lattice_samples` that fall in it (triangles crossing the
    near plane are skipped; huge triangles are sampled at most MAX_EDGE_SAMPLES steps per edge).
    """
    w, h = size
    depth = np.full(h * w, np.inf, dtype=np.float64)
    for chunk in lattice_samples(vertices, faces, K, pose, size):
        np.minimum.at(depth, chunk.flat[chunk.inside], chunk.points[chunk.inside, 2])
    return depth.reshape(h, w).astype(np.float32)


def shade(depth: np.ndarray, K: np.ndarray) -> np.ndarray:
    """Grey-shaded uint8 image of a depth map (normals from depth gradients, headlight)."""
    h, w = depth.shape
    valid = np.isfinite(depth)
    d = np.where(valid, depth, 0.0)
    u, v = np.meshgrid(np.arange(w), np.arange(h))
    pts = np.stack([(u - K[0, 2]) / K[0, 0] * d, (v - K[1, 2]) / K[1, 1] * d, d], -1)
    dx = np.gradient(pts, axis=1)
    dy = np.gradient(pts, axis=0)
    n = np.cross(dx, dy)
    n /= np.linalg.norm(n, axis=-1, keepdims=True) + 1e-12
    light = np.abs(n[..., 2])
    img = (40 + 200 * light).clip(0, 255)
    img[~valid] = 255
    return img.astype(np.uint8)
