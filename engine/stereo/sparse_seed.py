"""A depth map to start PatchMatch from, interpolated from the sparse points (SfM's, or the pose
refinement's triangulated ones), as OpenMVS initialises every depth map (DepthMap.cpp: a Delaunay
triangulation of the points the view sees, each pixel on its triangle's plane).

The points carry no record of which photos saw them, so a view's points are the ones in front of it,
inside it and within its depth range that no nearer point hides: in every VISIBILITY_CELL x
VISIBILITY_CELL cell of the image only the points within VISIBILITY_DEPTH of the cell's nearest are
kept (a point on the wall behind a chair projects next to the chair's points and is dropped). Each
pixel inside a triangle of the kept points takes the depth of the plane through the triangle's three
points; triangles seen nearly edge-on (bridging a depth jump) are left out, and so is everything
outside the points' hull. A wrong seed costs no more than the random plane it replaces: PatchMatch
scores it like any other candidate.

Arrays: image (h, w) at the stereo size; K in its pixels (pixel centres at +0.5); pose camera-to-world.
"""

from __future__ import annotations

import cv2
import numpy as np
import torch

from ..geometry.cameras import project_points
from .planar_prior import SUPPORT_MIN_COS, triangle_planes
from .plane_cost import plane_depth

VISIBILITY_CELL = 8  # pixels at the stereo size
VISIBILITY_DEPTH = 0.1  # relative: a point more than 10 % behind its cell's nearest is taken as hidden
MIN_POINTS = 8  # fewer points than this in view: no seed (a handful of triangles is not worth a start)


def visible_points(points: np.ndarray, K: np.ndarray, pose: np.ndarray, size: tuple[int, int],
                   depth_range: tuple[float, float]) -> tuple[np.ndarray, np.ndarray]:
    """The sparse points (N, 3) world that the view sees: pixel positions (M, 2) (u, v) and depths (M,)."""
    w, h = size
    u, v, z = project_points(points, K, pose)
    near, far = depth_range
    inside = (z >= near) & (z <= far) & (u >= 0) & (u < w) & (v >= 0) & (v < h)
    u, v, z = u[inside], v[inside], z[inside]
    if len(z) == 0:
        return np.zeros((0, 2)), np.zeros(0)
    cells_x = -(-w // VISIBILITY_CELL)
    cell = (v // VISIBILITY_CELL).astype(np.int64) * cells_x + (u // VISIBILITY_CELL).astype(np.int64)
    nearest = np.full(cell.max() + 1, np.inf)
    np.minimum.at(nearest, cell, z)
    seen = z <= nearest[cell] * (1.0 + VISIBILITY_DEPTH)
    return np.stack([u[seen], v[seen]], -1), z[seen]


def sparse_seed_depth(points: np.ndarray, K: np.ndarray, pose: np.ndarray, size: tuple[int, int],
                      depth_range: tuple[float, float]) -> np.ndarray:
    """(h, w) float32 depth (planar z, metres) of the view interpolated over a Delaunay triangulation of
    the sparse points it sees; 0 where no kept triangle covers a pixel (or too few points are in view)."""
    from scipy.spatial import Delaunay, QhullError  # defers scipy: not loaded when Blender registers the add-on

    w, h = size
    empty = np.zeros((h, w), np.float32)
    uv, z = visible_points(np.asarray(points, np.float64), K, pose, size, depth_range)
    if len(z) < MIN_POINTS:
        return empty
    try:
        triangles = Delaunay(uv).simplices  # (T, 3) into the points
    except QhullError:  # all on one line
        return empty
    K_inv = np.linalg.inv(K)
    rays_of = lambda u, v: np.stack([u, v, np.ones_like(u)], -1) @ K_inv.T  # noqa: E731  (z = 1; skew kept)
    corners = torch.as_tensor(rays_of(uv[:, 0], uv[:, 1]) * z[:, None])[triangles]  # (T, 3, 3) camera points
    normal, rho = triangle_planes(corners)
    centroid = corners.mean(1)
    facing = -(normal * centroid).sum(-1) / centroid.norm(dim=-1)
    # Every pixel's triangle (-1 where none), each kept triangle drawn with its index (as the planar
    # prior does: scipy's find_simplex is slow on many pixels).
    label = np.full((h, w), -1, np.int32)
    corner_px = np.floor(uv[triangles]).astype(np.int32)  # (T, 3, 2)
    for t in np.nonzero((facing > SUPPORT_MIN_COS).numpy())[0]:
        cv2.fillConvexPoly(label, corner_px[t], int(t))
    covered = label >= 0
    if not covered.any():
        return empty
    v, u = np.nonzero(covered)
    rays = torch.as_tensor(rays_of(u + 0.5, v + 0.5))
    triangle = torch.as_tensor(label[v, u].astype(np.int64))
    depth = plane_depth(normal[triangle], rho[triangle], rays).numpy()
    near, far = depth_range
    depth = np.where((depth >= near) & (depth <= far), depth, 0.0)
    seed = empty
    seed[v, u] = depth
    return seed
