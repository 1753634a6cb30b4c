"""The floor plane in SfM sparse points, found by RANSAC along gravity.

The metric scale of a photo-only capture comes from one number the user knows roughly, the
camera height above the floor; so the floor must be found reliably in the SfM points. A low
percentile of the point heights (the old estimate) lands on whatever is lowest: stray points
below the floor, or a table top when the floor is not seen. Here the floor is a *plane*:

- candidates are the sparse points below the cameras' median height (the floor is under them);
- RANSAC fits planes whose normal is within `MAX_TILT_DEG` of the gravity estimate (+Z after
  the camera-based gravity alignment); the inlier band is a fixed fraction of the cameras'
  height above the lowest points, so it works in SfM's arbitrary units;
- of the horizontal planes found (up to three, each fitted on the points the previous ones left),
  the floor is the lowest one that is well supported and is not an "orbited support": a small
  plane (its dense footprint under 30 % of the area the cameras enclose) inside the ring of
  cameras that the cameras stand beside, not over, is the table under an object they circle around
  (the fox capture), not the floor. A walk round a block (a U-shaped corridor) also rings a small
  footprint, but there the cameras stand over the floor they see: that keeps it a floor. A plane
  with many points well below it is not the floor either. These are heuristics:
  when they reject every plane, the caller says that no floor was found;
- the plane is refitted by least squares on its inliers; its normal then refines gravity when
  the support is large (`GRAVITY_MIN_INLIERS`), since a floor seen across the room measures "up"
  better than the mean of hand-held cameras' up vectors.

Everything here works in a gravity-aligned frame (Z roughly up) and in SfM units.
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Optional

import numpy as np

MAX_TILT_DEG = 20.0  # the floor's normal is within this of the gravity estimate (cameras looking down tilt it 10-15 deg)
MIN_FLOOR_POINTS = 20  # fewer candidate points below the cameras than this: the floor is not seen
MIN_FLOOR_INLIERS = 30  # a plane with fewer inliers is not trusted as the floor
MIN_INLIER_SHARE = 0.10  # ... nor one holding less than this share of the points below the cameras
GRAVITY_MIN_INLIERS = 150  # enough floor points to trust the plane's normal over the cameras' mean up
BAND_FRACTION = 0.015  # inlier band half-width, as a fraction of the cameras' height above the lowest points
MAX_SHARE_BELOW = 0.10  # a plane with more than this share of the candidates clearly below it is not the floor
MAX_ORBITED_AREA = 0.3  # a plane inside the camera ring smaller than this share of the ring's area is a table
MIN_CAMERAS_OVER = 0.5  # ... unless at least this share of the cameras stand over it (a corridor's floor)
OVER_CELLS = 2  # a camera stands over a plane when a dense cell of it lies within this many cells
FOOTPRINT_CELLS = 5  # footprint grid cell = camera height above the lowest points / this
RANSAC_ITERATIONS = 400
MAX_PLANES = 3


@dataclass(frozen=True)
class FloorPlane:
    """A horizontal-ish plane n . x = offset, n unit and pointing up (towards the cameras)."""

    normal: np.ndarray  # (3,) unit, in the frame of the points given to `find_floor_plane`
    offset: float  # n . x on the plane, in SfM units
    inliers: int  # points within the band of the plane
    candidates: int  # points below the cameras that were searched
    band: float  # inlier band half-width used, SfM units
    tilt_deg: float  # angle between the normal and +Z of the frame the points were given in
    area: float  # dense footprint of the inliers (grid cells with 3 or more points), SfM units squared
    orbited: bool  # a small plane inside the ring of cameras: the support of an object they circle around

    @property
    def inlier_share(self) -> float:
        return self.inliers / max(1, self.candidates)

    def heights(self, points: np.ndarray) -> np.ndarray:
        """Signed heights (N,) of `points` (N, 3) above the plane, SfM units."""
        return np.asarray(points, dtype=np.float64) @ self.normal - self.offset


@dataclass(frozen=True)
class FloorSearch:
    """What the search saw, for the report: the floor or why there is none."""

    plane: Optional[FloorPlane]
    candidates: int  # points below the cameras' median height
    reason: str  # empty when a plane was found, else one clause saying why not


def find_floor_plane(
    points: Optional[np.ndarray],
    camera_centres: np.ndarray,
    seed: int = 0,
    reject_orbited: bool = True,
) -> FloorSearch:
    """Find the floor in `points` (N, 3) under cameras at `camera_centres` (M, 3), Z roughly up.

    `reject_orbited=False` keeps small planes inside the ring of cameras: the ceiling search
    (scale.py, the world turned upside down) has no table to mistake, and a ceiling's sparse points
    are often too thin for the footprint grid. Deterministic for a given `seed`. Never raises on
    poor input: `FloorSearch.plane` is None and
    `reason` says why (too few points below the cameras, no horizontal plane under them, ...).
    """
    if points is None or len(points) == 0:
        return FloorSearch(None, 0, "there are no sparse points")
    pts = np.asarray(points, dtype=np.float64)
    cams = np.asarray(camera_centres, dtype=np.float64)
    camera_z = float(np.median(cams[:, 2]))
    below = pts[pts[:, 2] < camera_z]
    if len(below) < MIN_FLOOR_POINTS:
        return FloorSearch(None, len(below), f"only {len(below)} sparse points lie below the cameras")
    # The band scales with the scene: 1.5 % of the cameras' height above the lowest points
    # (~2 cm for a 1.5 m camera height). The 2nd percentile ignores a few strays below the floor.
    span = camera_z - float(np.percentile(below[:, 2], 2.0))
    if span <= 0:
        return FloorSearch(None, len(below), "the points below the cameras have no height to speak of")
    band = BAND_FRACTION * span

    rng = np.random.default_rng(seed)
    remaining = below
    planes: list[FloorPlane] = []
    for _ in range(MAX_PLANES):
        if len(remaining) < MIN_FLOOR_INLIERS:
            break
        plane = _ransac_horizontal_plane(remaining, band, rng)
        if plane is None:
            break
        normal, offset = plane
        mask = np.abs(remaining @ normal - offset) < band
        if mask.sum() < MIN_FLOOR_INLIERS:
            break
        normal, offset = _refined_plane(remaining[mask], band)
        inliers = int((np.abs(below @ normal - offset) < band).sum())
        planes.append(_described(below, cams, normal, offset, inliers, band, span))
        # Twice the band: the noisy tails of a plane must not come back as a plane of their own.
        remaining = remaining[np.abs(remaining @ normal - offset) >= 2.0 * band]

    accepted = _distinct([p for p in planes if _is_floor(p, below, reject_orbited)])
    if not accepted:
        if not planes:
            reason = f"no horizontal plane among the {len(below)} points below the cameras"
        else:
            best = max(planes, key=lambda p: p.inliers)
            reason = (f"the largest horizontal plane below the cameras ({best.inliers} of {len(below)} points) "
                      + ("is a small surface the cameras circle around (a table top?)" if best.orbited
                         else "is too small or has many points below it"))
        return FloorSearch(None, len(below), reason)
    lowest = min(accepted, key=lambda p: p.offset)
    return FloorSearch(lowest, len(below), "")


def _is_floor(plane: FloorPlane, below: np.ndarray, reject_orbited: bool = True) -> bool:
    if plane.inliers < MIN_FLOOR_INLIERS or plane.inlier_share < MIN_INLIER_SHARE:
        return False
    if plane.orbited and reject_orbited:
        return False
    clearly_below = float((plane.heights(below) < -3.0 * plane.band).mean())
    return clearly_below <= MAX_SHARE_BELOW


def _distinct(planes: list[FloorPlane]) -> list[FloorPlane]:
    """Planes at different heights: of two within three bands of each other, the better supported."""
    kept: list[FloorPlane] = []
    for plane in sorted(planes, key=lambda p: -p.inliers):
        if all(abs(plane.offset - k.offset) > 3.0 * k.band for k in kept):
            kept.append(plane)
    return kept


def _ransac_horizontal_plane(
    points: np.ndarray, band: float, rng: np.random.Generator
) -> Optional[tuple[np.ndarray, float]]:
    """(normal (3,), offset) of the near-horizontal plane with the most points within `band`."""
    cos_tilt = np.cos(np.radians(MAX_TILT_DEG))
    samples = rng.integers(0, len(points), size=(RANSAC_ITERATIONS, 3))
    a, b, c = points[samples[:, 0]], points[samples[:, 1]], points[samples[:, 2]]
    normals = np.cross(b - a, c - a)
    norms = np.linalg.norm(normals, axis=1)
    valid = norms > 1e-12
    normals[valid] /= norms[valid, None]
    normals *= np.where(normals[:, 2:3] < 0, -1.0, 1.0)  # point up
    valid &= normals[:, 2] >= cos_tilt
    if not valid.any():
        return None
    normals, a = normals[valid], a[valid]
    offsets = np.einsum("ij,ij->i", normals, a)
    # (hypotheses, points) distances in chunks: 400 x 20k floats is fine at once.
    counts = (np.abs(points @ normals.T - offsets) < band).sum(axis=0)
    best = int(np.argmax(counts))
    return normals[best], float(offsets[best])


def _refined_plane(points: np.ndarray, band: float) -> tuple[np.ndarray, float]:
    """Least-squares plane through the RANSAC inliers (N, 3), refitted twice on the points within
    3 robust sigmas: the band also holds the foot of every wall and object on the floor, which
    would tilt a plain fit."""
    normal, offset = _least_squares_plane(points)
    for _ in range(2):
        residual = np.abs(points @ normal - offset)
        sigma = 1.4826 * float(np.median(residual))
        keep = residual <= max(3.0 * sigma, 1e-3 * band)
        if keep.sum() < 3:
            break
        normal, offset = _least_squares_plane(points[keep])
    return normal, offset


def _least_squares_plane(points: np.ndarray) -> tuple[np.ndarray, float]:
    """Total least squares plane (normal up, offset) through `points` (N, 3)."""
    centre = points.mean(axis=0)
    _, _, vt = np.linalg.svd(points - centre, full_matrices=False)
    normal = vt[-1]
    if normal[2] < 0:
        normal = -normal
    return normal, float(normal @ centre)


def _described(
    below: np.ndarray, cams: np.ndarray, normal: np.ndarray, offset: float, inliers: int, band: float, span: float
) -> FloorPlane:
    on_plane = below[np.abs(below @ normal - offset) < band]
    tilt = float(np.degrees(np.arccos(np.clip(normal[2], -1.0, 1.0))))
    # A grid of dense cells, not the inliers' hull: every wall crosses the plane's band in a thin
    # line of points, which would make any plane look as wide as the room.
    cell = span / FOOTPRINT_CELLS
    keys, counts = np.unique(np.floor(on_plane[:, :2] / cell).astype(np.int64), axis=0, return_counts=True)
    dense = keys[counts >= 3]
    area = float(len(dense)) * cell * cell
    orbited = False
    ring = _convex_hull(cams[:, :2])
    if len(dense) and len(ring) >= 3:
        ring_area = _polygon_area(ring)
        centre = (dense.mean(axis=0) + 0.5) * cell
        orbited = (ring_area > 0 and area < MAX_ORBITED_AREA * ring_area and _inside(ring, centre)
                   and _share_over(cams[:, :2], dense, cell) < MIN_CAMERAS_OVER)
    return FloorPlane(normal, offset, inliers, len(below), band, tilt, area, orbited)


def _share_over(camera_xy: np.ndarray, dense: np.ndarray, cell: float) -> float:
    """Share of the cameras (M, 2) within OVER_CELLS cells of a dense footprint cell (K, 2 integer keys)."""
    camera_keys = np.floor(camera_xy / cell).astype(np.int64)
    gaps = np.abs(camera_keys[:, None, :] - dense[None, :, :]).max(axis=2)  # (M, K) Chebyshev distance in cells
    return float((gaps.min(axis=1) <= OVER_CELLS).mean())


def _polygon_area(polygon: np.ndarray) -> float:
    x, y = polygon[:, 0], polygon[:, 1]
    return 0.5 * abs(float(np.dot(x, np.roll(y, -1)) - np.dot(y, np.roll(x, -1))))


def _inside(hull: np.ndarray, point: np.ndarray) -> bool:
    """Point (2,) inside a counter-clockwise convex polygon (K, 2): left of (or on) every edge."""
    edges = np.roll(hull, -1, axis=0) - hull
    rel = point[None, :] - hull
    return bool((edges[:, 0] * rel[:, 1] - edges[:, 1] * rel[:, 0] >= 0).all())


def _convex_hull(xy: np.ndarray) -> np.ndarray:
    """Counter-clockwise convex hull (K, 2) of points (N, 2): Andrew's monotone chain."""
    pts = np.unique(xy, axis=0)
    if len(pts) < 3:
        return pts

    def half(sequence: np.ndarray) -> list[np.ndarray]:
        chain: list[np.ndarray] = []
        for p in sequence:
            while len(chain) >= 2:
                o, a = chain[-2], chain[-1]
                if (a[0] - o[0]) * (p[1] - o[1]) - (a[1] - o[1]) * (p[0] - o[0]) > 0:
                    break
                chain.pop()
            chain.append(p)
        return chain

    lower, upper = half(pts), half(pts[::-1])
    return np.array(lower[:-1] + upper[:-1])
