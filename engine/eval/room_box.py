"""The "room box" baseline: a plain axis-aligned box room fitted to the scene.

Its F-score is the floor we report beside real results: a method that does not beat an empty box
has learned nothing about the room's contents.
"""

from __future__ import annotations

import numpy as np

from ..mesh_io import Mesh
from ..tsdf.volume import TsdfVolume

# Corner k of the box has coordinates (bit0 ? hi : lo) per axis.
_CORNERS = np.array([[(k >> 0) & 1, (k >> 1) & 1, (k >> 2) & 1] for k in range(8)])
# The six sides as corner loops; box_mesh winds their triangles so normals face INTO the box.
# A box side needs this fraction of the fullest plane's points on its half of the axis: more than a
# patch seen through a window (test_eval), less than a wall seen only in part (the far walls of a
# rendered room, beyond the 3 m depth cap of the ground truth).
PLANE_FRACTION = 0.25
_QUADS = [(0, 1, 3, 2), (4, 5, 7, 6), (0, 1, 5, 4), (2, 3, 7, 6), (0, 2, 6, 4), (1, 3, 7, 5)]


def box_mesh(lo: np.ndarray, hi: np.ndarray) -> Mesh:
    """Closed axis-aligned box [lo, hi] (each (3,) metres) as 8 vertices and 12 inward-facing triangles."""
    lo, hi = np.asarray(lo, np.float64), np.asarray(hi, np.float64)
    vertices = np.where(_CORNERS == 1, hi, lo).astype(np.float32)
    faces = np.array([[a, b, c] for a, b, c, d in _QUADS] + [[a, c, d] for a, b, c, d in _QUADS], np.int32)
    # Flip triangles whose normal points away from the centre (we look at rooms from inside).
    v = vertices.astype(np.float64)
    normal = np.cross(v[faces[:, 1]] - v[faces[:, 0]], v[faces[:, 2]] - v[faces[:, 0]])
    outward = np.einsum("ij,ij->i", normal, (lo + hi) / 2 - v[faces].mean(axis=1)) < 0
    faces[outward] = faces[outward][:, ::-1]
    return Mesh(vertices, faces)


def fit_room_box(points: np.ndarray, bin_size: float = 0.04) -> Mesh:
    """Axis-aligned box whose sides sit on the outermost large planes of surface points (N, 3).

    Per axis, the coordinates are histogrammed (bin_size) inside their 1 %..99 % range; the lower side
    is the lowest bin of the lower half holding at least `PLANE_FRACTION` of that half's fullest bin,
    the upper side likewise the highest bin of the upper half. Floor, walls and ceiling are large
    planes at the outside of a room, so they win over furniture (a table top is large but inside),
    and surfaces seen through doors and windows (beyond the walls, sparse) cannot drag the box
    outward as an extent would. Use `box_mesh` directly for known bounds.
    """
    points = np.asarray(points, np.float64).reshape(-1, 3)
    if len(points) == 0:
        raise ValueError("fit_room_box needs at least one point")
    lo, hi = np.zeros(3), np.zeros(3)
    for axis in range(3):
        c = points[:, axis]
        a, b = np.quantile(c, [0.01, 0.99])
        if b - a < 2 * bin_size:
            lo[axis], hi[axis] = a, b
            continue
        edges = np.arange(a, b + bin_size, bin_size)
        counts, edges = np.histogram(c, bins=edges)
        centres = (edges[:-1] + edges[1:]) / 2
        half = len(counts) // 2
        lower, upper = counts[:half], counts[half:]
        lo[axis] = centres[:half][np.flatnonzero(lower >= PLANE_FRACTION * lower.max())[0]]
        hi[axis] = centres[half:][np.flatnonzero(upper >= PLANE_FRACTION * upper.max())[-1]]
    return box_mesh(lo, hi)


def room_box_from_tsdf(volume: TsdfVolume) -> Mesh:
    """Room box fitted to the voxels next to a surface (|tsdf| < 0.5, i.e. within 6 cm) of a TSDF."""
    near = (np.abs(volume.tsdf) < 0.5) & volume.observed
    return fit_room_box(volume.positions()[near], bin_size=volume.voxel_size)
