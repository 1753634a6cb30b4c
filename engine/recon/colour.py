"""Occlusion-aware vertex colours from the photos.

A vertex takes colour only from views that actually see it: for each colour view the mesh itself is
rendered into a low-resolution depth map (a numpy z-buffer of points sampled on every triangle at
sub-pixel spacing), and a vertex is accepted when its depth is within a tolerance of that map and it
faces the camera. Accepted colours are averaged with weight cos(viewing angle), so grazing views,
which smear texture, count less. Vertices that no view sees are grey.

The photo lookups themselves (depth map, visibility, bilinear sampling, the grey) are
`engine/photo_sampling.py`, shared with the texture bake.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import TYPE_CHECKING, Optional

import numpy as np

from ..capture.images import load_resized, resized_size
from ..geometry.cameras import scale_intrinsics
from ..jobs import CancelToken, ProgressCallback, check, report
from ..mesh_io import Mesh
from ..photo_sampling import UNSEEN_GREY, occlusion_depth, sample_bilinear, visible_points

if TYPE_CHECKING:
    from .plan import ReconPlan
    from .settings import ReconSettings

COLOUR_LONG_SIDE = 320  # photos are sampled for colour at (at most) this size: vertices are 4 cm apart


@dataclass
class ColourView:
    image: np.ndarray  # (h, w, 3) uint8 RGB
    K: np.ndarray  # (3, 3) in pixels of `image`
    pose: np.ndarray  # (4, 4) camera-to-world, OpenCV axes


def visible_vertices(
    mesh: Mesh, view: ColourView, depth: np.ndarray, tolerance: float
) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
    """Which vertices `view` sees: (ids (M,) int64, u (M,), v (M,), cosine (M,)); see `visible_points`.

    `depth` may have fewer pixels than `view.image` (same field of view); u, v are image pixels.
    """
    h, w = view.image.shape[:2]
    ids, u, v, cosine, _ = visible_points(mesh.vertices, mesh.normals, view.K, view.pose, (w, h), depth, tolerance)
    return ids, u, v, cosine


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
        # Occlusion is resolved at <= DEPTH_LONG_SIDE (photo_sampling) pixels: about 2 cm per pixel at 3 m, finer than
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
