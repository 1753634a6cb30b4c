"""A plane's grid of cells: where a plane's surface was seen, where it is added, and its mesh.

The finishing (`finishing.py`) lays one over each structural plane and each furniture plane
(`furniture.py`); the cells are the voxel size, in the plane's own (u, v) coordinates.
"""

from __future__ import annotations

from dataclasses import dataclass

import numpy as np
from scipy import ndimage

from .planes import StructuralPlane

FLAT_BAND_SIGMAS = 2.5
MIN_FLAT_BAND = 0.02  # m
RELIEF_MIN_AREA = 0.04  # m^2 of cells off the plane's band (and none on it) together: relief, not crumple


@dataclass
class PlaneGrid:
    """One plane's cells: origin (2,) in-plane coordinates of cell (0, 0)'s corner, cell size, and the
    masks (A, B) bool of cells the surface covered (`observed`), free space by the votes (`free`,
    reported), where seeing through outvotes surface (`open`: doors, windows) and the finished surface's
    cells (`keep` = observed, or added where nothing contradicts it). `shift` (A, B) float: where the
    surface stands along the plane's normal, per cell, in metres off the plane (`local_shift`); `band` m:
    the plane's noise (`flat_band`); `relief` (A, B) bool: patches of cells with surface near the plane
    but off it by more than the band, and none within it (kept as they are, never covered)."""

    plane: StructuralPlane
    origin: np.ndarray
    cell: float
    observed: np.ndarray
    free: np.ndarray
    keep: np.ndarray
    open: np.ndarray
    shift: np.ndarray
    relief: np.ndarray
    band: float

    @property
    def added(self) -> np.ndarray:
        return self.keep & ~self.observed

    def centres(self) -> np.ndarray:
        """(A * B, 3) world centres of the cells, raveled, on the surface where it stands (`shift`)."""
        ii, jj = np.meshgrid(np.arange(self.keep.shape[0]), np.arange(self.keep.shape[1]), indexing="ij")
        coords = self.origin + (np.stack([ii.ravel(), jj.ravel()], axis=1) + 0.5) * self.cell
        return self.plane.from_plane(coords) + self.shift.reshape(-1, 1) * self.plane.normal

    def cells_of(self, coords: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
        """(i (N,), j (N,), inside (N,) bool) of in-plane coordinates (N, 2)."""
        index = np.floor((coords - self.origin) / self.cell).astype(np.int64)
        inside = (index >= 0).all(axis=1) & (index[:, 0] < self.keep.shape[0]) & (index[:, 1] < self.keep.shape[1])
        return np.clip(index[:, 0], 0, self.keep.shape[0] - 1), np.clip(index[:, 1], 0, self.keep.shape[1] - 1), inside

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance of world points (N, 3) from the surface where it stands: the plane moved
        by its `shift` at their cell (the nearest cell outside the grid)."""
        i, j, _ = self.cells_of(self.plane.to_plane(points))
        return self.plane.distance(points) - self.shift[i, j]

    def within(self, points: np.ndarray, reach: float) -> np.ndarray:
        """(M,) int64 indices of the world points (N, 3) that may lie within `reach` m of the surface where
        it stands: those within reach + the largest shift of the plane (one dot product each, so the
        cell lookups of `distance` and `covers` run on these only)."""
        return np.flatnonzero(np.abs(self.plane.distance(points)) <= reach + float(np.abs(self.shift).max(initial=0.0)))

    def blocks(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: world points (N, 3) project onto cells where the views saw the plane's own surface
        (`observed`, grown by a cell), away from its openings (cells a view saw through, grown by a cell):
        there the views show the plane standing in front of whatever lies behind it. Not the rest of its
        extent, where the plane is only fitted and nothing the views saw stands in front (the ARKitScenes
        kitchen's recall +0.003, the corridor's +0.003, SUN3D and the demo within a run's spread;
        docs/experiments.md, "Real rooms decide")."""
        i, j, inside = self.cells_of(self.plane.to_plane(points))
        opening = ndimage.binary_dilation(self.open, iterations=1)
        seen = ndimage.binary_dilation(self.observed, iterations=1)
        return inside & seen[i, j] & ~opening[i, j]

    def refute(self, points: np.ndarray) -> None:
        """Surface seen where it is, at world points (N, 3) behind the plane, says the plane does not stand
        in front of it: their cells (grown by a cell) are neither added nor blocking (`blocks`), as an
        opening's are. Cells the surface covered stay."""
        if len(points) == 0:
            return
        i, j, inside = self.cells_of(self.plane.to_plane(points))
        refuted = np.zeros_like(self.keep)
        refuted[i[inside], j[inside]] = True
        refuted = ndimage.binary_dilation(refuted, iterations=1)
        self.open |= refuted & ~self.observed
        self.keep &= ~(refuted & ~self.observed)

    def in_relief(self, points: np.ndarray) -> np.ndarray:
        """(N,) bool: world points (N, 3) project into a relief cell."""
        i, j, inside = self.cells_of(self.plane.to_plane(points))
        return inside & self.relief[i, j]

    def covers(self, points: np.ndarray, dilate: int = 1) -> np.ndarray:
        """(N,) bool: world points (N, 3) project into a kept cell (grown by `dilate` cells)."""
        mask = ndimage.binary_dilation(self.keep, iterations=dilate) if dilate else self.keep
        i, j, inside = self.cells_of(self.plane.to_plane(points))
        return inside & mask[i, j]


def grid_mesh(grid: PlaneGrid, cells: np.ndarray) -> tuple[np.ndarray, np.ndarray]:
    """(vertices (V, 3) float64, faces (F, 3) int64) of the `cells` (A, B) bool of a grid: two triangles
    per cell wound so their normal is the plane's, corners shared between neighbouring cells."""
    i, j = np.nonzero(cells)
    if len(i) == 0:
        return np.zeros((0, 3)), np.zeros((0, 3), np.int64)
    width = cells.shape[1] + 1
    corners = np.stack([i * width + j, (i + 1) * width + j, (i + 1) * width + j + 1, i * width + j + 1], axis=1)
    used, inverse = np.unique(corners, return_inverse=True)
    corners = inverse.reshape(-1, 4)
    corner_ij = np.stack([used // width, used % width], axis=1)
    coords = grid.origin + corner_ij * grid.cell
    # A corner's shift is the mean of the cells around it (cell centres sit half a cell in).
    shift = ndimage.map_coordinates(grid.shift, (corner_ij - 0.5).T, order=1, mode="nearest")
    faces = np.concatenate([corners[:, [0, 1, 2]], corners[:, [0, 2, 3]]])
    return grid.plane.from_plane(coords) + shift[:, None] * grid.plane.normal, faces


def flat_band(residual: np.ndarray, tolerance: float) -> float:
    """The m within which surface is the plane: FLAT_BAND_SIGMAS times the robust spread (1.4826 x the
    median absolute deviation) of the `residual`s (N,) of its faces from where it stands, at least
    MIN_FLAT_BAND and at most `tolerance` (LiDAR's walls lie within about a centimetre, stereo's crumple
    over the whole tolerance)."""
    if len(residual) < 10:
        return tolerance
    spread = 1.4826 * float(np.median(np.abs(residual - np.median(residual))))
    return float(np.clip(FLAT_BAND_SIGMAS * spread, MIN_FLAT_BAND, tolerance))


def stretches_of_area(mask: np.ndarray, cell: float, min_area: float) -> np.ndarray:
    """(A, B) bool: the cells of `mask` (A, B) bool (cells of `cell` m) in 8-connected stretches of at
    least `min_area` m^2."""
    labels, count = ndimage.label(mask, structure=np.ones((3, 3), bool))
    if not count:
        return np.zeros(mask.shape, bool)
    big = np.bincount(labels.ravel(), minlength=count + 1) * cell ** 2 >= min_area
    big[0] = False
    return big[labels]


def local_shift(shape: tuple[int, int], i: np.ndarray, j: np.ndarray, distance: np.ndarray, weights: np.ndarray,
                sigma_cells: float) -> np.ndarray:
    """(A, B) float of a grid of `shape`: the weighted mean of the `distance`s (N,) of surface in cells
    (i, j) (N,) each, smoothed by a Gaussian of `sigma_cells` (a normalised convolution, so empty cells
    take their surroundings' value); cells farther than the Gaussian reaches take the nearest value, and
    a grid with no surface none (0)."""
    if len(i) == 0:
        return np.zeros(shape)
    total = np.bincount(i * shape[1] + j, weights * distance, minlength=shape[0] * shape[1]).reshape(shape)
    weight = np.bincount(i * shape[1] + j, weights, minlength=shape[0] * shape[1]).reshape(shape)
    total, weight = (ndimage.gaussian_filter(x, sigma_cells, mode="constant", truncate=3.0) for x in (total, weight))
    defined = weight > 1e-6 * weight.max()
    shift = np.where(defined, total / np.maximum(weight, 1e-12), 0.0)
    if not defined.all():
        nearest = ndimage.distance_transform_edt(~defined, return_distances=False, return_indices=True)
        shift = shift[nearest[0], nearest[1]]
    return shift
