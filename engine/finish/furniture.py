"""Furniture planes: the flat pieces inside a room, found in its surface, flattened and closed (issue 44).

A kitchen or an office is mostly planes beyond its walls too: table and desk tops, counters, shelves,
cabinet fronts, partitions. Stereo leaves each of them crumpled by a few centimetres, and the
structural planes (`planes.py`) do not take them: they bound no room. They are found here as the
walls are, in the room's levelled Manhattan frame, but patch by patch instead of across the room:

- candidates: for up (tops) and each of the room's four wall directions (fronts), the area-weighted
  histogram of the position of the faces turned that way (within FACING_DEG: crumpled stereo is)
  gives planes; the faces within WINDOW of a peak, rasterised on a PATCH_CELL grid in the plane,
  split into connected patches;
- a patch is a furniture plane when it is furniture-sized (MIN_PATCH_AREA to MAX_PATCH_AREA of surface,
  MIN_PATCH_WIDTH across: a strip is a frame or an edge), flat (its surface's robust spread about its fitted plane within
  MAX_SPREAD, and not curved: a quadratic explains at most MAX_CURVED_SHARE of that spread) and not a
  structural plane or the floor;
- its grid (`grid.PlaneGrid`, cells of the voxel size, on the plane) covers its seen cells, plus the
  holes inside its seen outline that some view frames and none saw through (a highlight's gap in a
  glossy cabinet front); where the depth maps' median surface stands off the plane by RELIEF_DEPTH over
  a patch (`free_space.surface_offsets`: a bookcase's shelves behind its frame) is relief, kept as it
  is. Nothing outside the outline is added; curved and small things stay as they are.

Replacing the surface on a patch by its grid is the finishing's job (`finishing.finish_mesh`, mode room).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional, Sequence

import numpy as np
from scipy import ndimage

from .free_space import DepthView, surface_offsets, view_votes
from .grid import RELIEF_MIN_AREA, PlaneGrid, flat_band, stretches_of_area
from .planes import FLOOR, FURNITURE_MAX_AREA, StructuralPlane, _directions, _histogram_peaks, _refine_offset, _weighted_median, rotation_to_z

TOP, FRONT = "top", "front"  # plane kinds: facing up (tables, counters, shelves), facing sideways (fronts, partitions)
FACING_DEG = 45.0  # a face turned within this of a patch's normal is its surface (crumpled stereo is)
WINDOW = 0.1  # m either side of a patch's plane: its surface (SUN3D's stereo spreads a partition over +-10 cm)
PATCH_CELL = 0.1  # m: the grid candidate faces are split into connected patches on
OCCUPIED_SHARE = 0.15  # of a PATCH_CELL's area covered by candidate faces: the cell is the patch's
MIN_PATCH_AREA = 0.25  # m^2 of surface: a chair's back or seat is smaller, a cabinet front or a shelf is not
# A patch bigger than furniture is a wall the structural planes did not take (the 3D Scanner App
# corridor's inner walls: 12-24 m^2 patches); laid on one plane it loses the drift the walls' own grids
# follow (that corridor's LiDAR run: within 5 cm 0.823 -> 0.804 with them).
MAX_PATCH_AREA = FURNITURE_MAX_AREA
MIN_PATCH_WIDTH = 0.25  # m across its narrower axis (RMS width): a door frame or a table's edge is narrower
MAX_SPREAD = 0.05  # m: the robust spread of a patch's surface about its plane (a curved back is wider)
# Of a patch's surface's variance about its plane, the share a quadratic over the plane explains: a
# curved surface's is systematic (a half cylinder of 0.4 m radius: over 0.9), stereo's crumple is not
# (SUN3D's partitions and desks: 0.02-0.33; one of its ten patches 0.59, the demo room's three of twelve
# 0.52-0.88, refused).
MAX_CURVED_SHARE = 0.5
MAX_TILT_DEG = 10.0  # a patch's fitted plane may lean this far off the room's direction, else it keeps the direction
# The depth maps' median surface this far off a patch's plane, over RELIEF_MIN_AREA (grid.py), is relief:
# the demo room's bookcase shelves stand 3-10 cm behind its frame, and flattened they cost 0.02 recall.
RELIEF_DEPTH = 0.035  # m
MIN_TOP_HEIGHT = 0.1  # m above the floor: lower up-facing surface is the floor's own


@dataclass
class FurnitureCandidate:
    """A patch found in the surface: its plane (world, normal toward the side it was seen from, axes
    as a wall's or the floor's), its faces (indices into the mesh's faces) and their robust spread (m)
    about the plane."""

    plane: StructuralPlane
    faces: np.ndarray
    spread: float


def _axes(kind: str, normal: np.ndarray, heading: float) -> np.ndarray:
    """(2, 3) in-plane axes of a plane with unit `normal` in the levelled frame: a top's as the floor's
    (u along the heading), a front's as a wall's (u horizontal, v as near +Z as the normal allows)."""
    z = np.array([0.0, 0.0, 1.0])
    u = np.array([np.cos(heading), np.sin(heading), 0.0]) if kind == TOP else np.cross(z, normal)
    u = u - (u @ normal) * normal
    u /= np.linalg.norm(u)
    return np.stack([u, np.cross(normal, u)])


def _patches(coords: np.ndarray, areas: np.ndarray) -> tuple[np.ndarray, int]:
    """(label (N,) int, count) of faces at in-plane coords (N, 2) with `areas` (N,): 0 for faces in no
    patch, else the connected patch of PATCH_CELL cells they cover."""
    index = np.floor((coords - coords.min(axis=0)) / PATCH_CELL).astype(np.int64)
    shape = tuple(index.max(axis=0) + 1)
    covered = np.zeros(shape)
    np.add.at(covered, (index[:, 0], index[:, 1]), areas)
    occupied = covered >= OCCUPIED_SHARE * PATCH_CELL ** 2
    occupied = ndimage.binary_closing(occupied, structure=np.ones((3, 3), bool), border_value=0) | occupied
    labels, count = ndimage.label(occupied, structure=np.ones((3, 3), bool))
    return labels[index[:, 0], index[:, 1]], count


def _rms_width(coords: np.ndarray, weights: np.ndarray) -> float:
    """The narrower axis's width of points (N, 2) weighted by `weights`: sqrt(12 x its variance), which
    is the side of a uniformly covered rectangle."""
    centred = coords - np.average(coords, axis=0, weights=weights)
    covariance = (centred * weights[:, None]).T @ centred / max(weights.sum(), 1e-12)
    return float(np.sqrt(12.0 * max(np.linalg.eigvalsh(covariance)[0], 0.0)))


def _fit_plane(points: np.ndarray, weights: np.ndarray, direction: np.ndarray) -> tuple[np.ndarray, float, float]:
    """(unit normal (3,), offset, robust spread m) of the plane through points (N, 3) weighted by
    `weights`: the weighted principal plane, turned `direction`'s way, or `direction` itself when the
    fit leans more than MAX_TILT_DEG off it; the offset is the weighted median, the spread 1.4826 x the
    weighted median absolute deviation."""
    centre = np.average(points, axis=0, weights=weights)
    centred = points - centre
    _, vectors = np.linalg.eigh((centred * weights[:, None]).T @ centred)
    normal = vectors[:, 0] * np.sign(vectors[:, 0] @ direction)
    if normal @ direction < np.cos(np.radians(MAX_TILT_DEG)):
        normal = direction
    distance = points @ normal
    offset = _weighted_median(distance, weights)
    return normal, offset, 1.4826 * _weighted_median(np.abs(distance - offset), weights)


def _curved_share(points: np.ndarray, weights: np.ndarray, normal: np.ndarray, offset: float) -> float:
    """The share of the weighted variance of points' (N, 3) distances from the plane (unit `normal`,
    `offset`) that a quadratic in the in-plane coordinates explains (0: noise about a plane; 1: a
    smooth curved surface)."""
    distance = points @ normal - offset
    u = np.cross(normal, [1.0, 0.0, 0.0] if abs(normal[0]) < 0.9 else [0.0, 1.0, 0.0])
    u /= np.linalg.norm(u)
    a, b = points @ u, points @ np.cross(normal, u)
    a, b = a - np.average(a, weights=weights), b - np.average(b, weights=weights)
    design = np.stack([np.ones_like(a), a, b, a * a, a * b, b * b], axis=1)
    root = np.sqrt(weights)[:, None]
    coefficients, *_ = np.linalg.lstsq(design * root, distance * root[:, 0], rcond=None)
    centred = distance - np.average(distance, weights=weights)
    total = float(np.sum(weights * centred ** 2))
    left = float(np.sum(weights * (distance - design @ coefficients) ** 2))
    return 0.0 if total <= 0 else max(0.0, 1.0 - left / total)


def find_furniture_planes(centroids: np.ndarray, areas: np.ndarray, normals: np.ndarray, up: np.ndarray,
                          heading_deg: float, structural: Sequence[StructuralPlane],
                          candidate: Optional[np.ndarray] = None) -> list[FurnitureCandidate]:
    """The furniture patches (module doc) of a mesh's faces: centroids (F, 3), areas (F,), unit normals
    (F, 3) in the world; `up` (3,) the room's up and `heading_deg` its Manhattan heading in the frame
    levelled by it (as `planes.find_structural_planes` reports it); `structural` the room's planes;
    `candidate` (F,) bool the faces that may belong to a patch (None: all). Biggest patches first."""
    rotation = rotation_to_z(up)
    c, n = centroids @ rotation.T, normals @ rotation.T
    allowed = np.ones(len(c), bool) if candidate is None else candidate
    heading = float(np.radians(heading_deg))
    floor = next((p for p in structural if p.kind == FLOOR), None)
    cos_facing = np.cos(np.radians(FACING_DEG))
    found: list[FurnitureCandidate] = []
    for kind, direction in [(TOP, np.array([0.0, 0.0, 1.0]))] + [(FRONT, d) for d in _directions(heading)]:
        facing = allowed & (n @ direction > cos_facing)
        position = c @ direction
        world_direction = direction @ rotation
        for peak, _ in _histogram_peaks(position[facing], areas[facing], MIN_PATCH_AREA, WINDOW):
            offset = _refine_offset(position[facing], areas[facing], peak, WINDOW)
            if any(p.normal @ world_direction > 0.99 and abs(p.offset - offset) < WINDOW for p in structural):
                continue  # a wall, the floor or the ceiling: the structural planes' own
            if kind == TOP and floor is not None and offset - floor.offset < MIN_TOP_HEIGHT:
                continue
            near = np.flatnonzero(facing & (np.abs(position - offset) <= WINDOW))
            if len(near) < 10:
                continue
            axes = _axes(kind, direction, heading)
            coords = c[near] @ axes.T
            labels, count = _patches(coords, areas[near])
            for label in range(1, count + 1):
                members = near[labels == label]
                area = float(areas[members].sum())
                if not MIN_PATCH_AREA <= area <= MAX_PATCH_AREA or _rms_width(coords[labels == label], areas[members]) < MIN_PATCH_WIDTH:
                    continue
                normal, fitted, spread = _fit_plane(c[members], areas[members], direction)
                if spread > MAX_SPREAD or _curved_share(c[members], areas[members], normal, fitted) > MAX_CURVED_SHARE:
                    continue
                # n . (R x) = (R^T n) . x: the offset stays, normal and axes turn back.
                plane = StructuralPlane(kind, normal @ rotation, fitted, area, _axes(kind, normal, heading) @ rotation)
                found.append(FurnitureCandidate(plane, members, spread))
    found.sort(key=lambda f: -f.plane.area)
    return found


def furniture_grid(found: FurnitureCandidate, centroids: np.ndarray, cell: float, views: Sequence[DepthView],
                   fill: bool) -> PlaneGrid:
    """The patch's cells (`grid.PlaneGrid` of `cell` m, no shift: the patch is its plane), from its faces
    (centroids (F, 3) of the mesh's): observed where they lie; relief where the depth maps' median
    surface stands RELIEF_DEPTH or more off the plane over RELIEF_MIN_AREA (a bookcase's shelves behind
    its frame: kept as they are); kept, with `fill`, also the holes inside the observed outline that
    some view frames and none saw through; all of it only in stretches of MIN_PATCH_AREA or more."""
    plane = found.plane
    coords = plane.to_plane(centroids[found.faces])
    origin = coords.min(axis=0) - cell
    shape = tuple(int(x) for x in np.ceil((coords.max(axis=0) + cell - origin) / cell).astype(np.int64))
    empty = np.zeros(shape, bool)
    grid = PlaneGrid(plane, origin, cell, empty.copy(), empty.copy(), empty.copy(), empty.copy(), np.zeros(shape),
                     empty.copy(), flat_band(plane.distance(centroids[found.faces]), WINDOW))
    i, j, _ = grid.cells_of(coords)
    grid.observed[i, j] = True
    standing = surface_offsets(grid.centres(), plane.normal, plane.offset, views, 2 * WINDOW).reshape(shape)
    deep = np.abs(np.nan_to_num(standing)) > RELIEF_DEPTH
    grid.relief = stretches_of_area(deep, cell, RELIEF_MIN_AREA) & ndimage.binary_dilation(grid.observed, iterations=1)
    grid.observed = ndimage.binary_closing(grid.observed, structure=np.ones((3, 3), bool), border_value=0) | grid.observed
    grid.observed &= ~grid.relief
    votes = view_votes(grid.centres(), views, plane_normal=plane.normal)
    grid.free = votes.free().reshape(shape)
    grid.open = votes.contradicted().reshape(shape)
    grid.keep = grid.observed.copy()
    if fill:
        inside = ndimage.binary_fill_holes(grid.observed | grid.relief) & ~grid.relief
        grid.keep |= inside & ((votes.in_view >= 1) & ~votes.contradicted()).reshape(shape)
    # A stretch smaller than furniture (the patch cut up by its relief) would be a floater of its own:
    # the surface there stays as it was.
    grid.keep &= stretches_of_area(grid.keep, cell, MIN_PATCH_AREA)
    grid.observed &= grid.keep
    return grid
