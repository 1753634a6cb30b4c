"""What the other views confirm of a depth map: the geometric filter keeps only what they confirm,
and `adopt_confirmed_planes` gives a depth that no other view confirms the plane of a neighbouring
pixel that they do.

Where PatchMatch goes wrong on real photos (docs/experiments.md, "Depth maps smoothed along their
planes"): at depth edges its 9 x 9 window (a 17 px footprint at 200 px) carries the nearer surface
over the edge, and on fine repeating texture (carpet) it can settle on a plane that matches well by
chance. Such a depth is seen by no other view where it puts the surface: no other map confirms it
(`confirmations_at`: within 1 %, 1 px and 25 deg). Its neighbours on the right side of the
edge hold the plane that is there. So each unconfirmed depth tries the planes of its neighbours
`OFFSET_RADII` pixels away in the 8 directions (the plane's depth along this pixel's ray), and takes
the one the most other maps confirm, if any does. Only depths that are themselves confirmed vouch
for a plane: a depth the window fattened in one map would otherwise confirm the same wrong plane in
another view's pixels that no other view sees. As the geometric filter would, it acts on what the
other views say; unlike the filter, it drops nothing: a depth no neighbour's plane
can replace stays.

Confirmations are counted against the maps as they were before any depth changed, so the result does
not depend on the order of the maps. Maps without normals (the fast sweep's) are left alone.
"""

from __future__ import annotations

from concurrent.futures import ThreadPoolExecutor
from dataclasses import replace
from typing import Optional, Sequence

import numpy as np

from ..geometry.cameras import pixels_to_world, project_points
from .depth_map import DepthMap

CONSISTENCY_NEIGHBOURS = 6  # references a depth is checked against (more when more confirmations are asked for)
GEOMETRIC_RELATIVE_DEPTH = 0.01  # OpenMVS / MVSNet: two depths agree within 1 %...
GEOMETRIC_REPROJECTION_PX = 1.0  # ...the point comes back within 1 px...
GEOMETRIC_NORMAL_DEG = 25.0  # ...and the normals within 25 deg (where both maps have normals)
# A point is looked at closely only where the other map's depth is within NEAR_FACTOR x the agreement of
# the point's depth in that view. The agreement is judged in this view; the depth step between the two
# points seen from a view turned by up to 75 deg from the other is at least a quarter of it.
NEAR_FACTOR = 4.0


def filter_geometric(maps: list[DepthMap], min_views: int, relative_depth: float = GEOMETRIC_RELATIVE_DEPTH,
                     reprojection_px: float = GEOMETRIC_REPROJECTION_PX, normal_deg: float = GEOMETRIC_NORMAL_DEG) -> None:
    """Drop, in place, depths that fewer than `min_views` other maps confirm (`geometric_confirmations`)."""
    for m, (v, u, count) in zip(maps, geometric_confirmations(maps, min_views, relative_depth, reprojection_px, normal_deg)):
        drop = count < min_views
        m.depth[v[drop], u[drop]] = 0.0
        m.confidence[v[drop], u[drop]] = 0.0


def geometric_confirmations(maps: list[DepthMap], min_views: int, relative_depth: float = GEOMETRIC_RELATIVE_DEPTH,
                            reprojection_px: float = GEOMETRIC_REPROJECTION_PX, normal_deg: float = GEOMETRIC_NORMAL_DEG
                            ) -> list[tuple[np.ndarray, np.ndarray, np.ndarray]]:
    """Per map, the rows v, columns u and confirmation counts (each (D,)) of its D depths
    (`confirmations_at`, against the CONSISTENCY_NEIGHBOURS or `min_views` nearest other maps)."""
    counts = []
    for a, m in enumerate(maps):
        v, u = np.nonzero(m.depth > 0)
        normals = m.normal[v, u] if m.normal is not None else None
        counts.append((v, u, confirmations_at(maps, a, v, u, m.depth[v, u], normals, min_views, relative_depth,
                                              reprojection_px, normal_deg)))
    return counts


def confirmations_at(maps: list[DepthMap], a: int, v: np.ndarray, u: np.ndarray, depth: np.ndarray,
                     normal: Optional[np.ndarray], min_views: int = 1, relative_depth: float = GEOMETRIC_RELATIVE_DEPTH,
                     reprojection_px: float = GEOMETRIC_REPROJECTION_PX, normal_deg: float = GEOMETRIC_NORMAL_DEG
                     ) -> np.ndarray:
    """(D,) how many other maps confirm the points of map `a` at rows v, columns u (each (D,)) with
    depths `depth` (D,) and camera-frame normals `normal` (D, 3) or None (not necessarily the map's own).
    Another map confirms a point when the point projects into it, its depth there (nearest pixel)
    brought back into this view lands within `reprojection_px` of the pixel and within `relative_depth`
    of the depth, and (where both have normals) the normals agree within `normal_deg`. Checked against
    every other map that shares the view's depth range, nearest camera first (CONSISTENCY_NEIGHBOURS
    or `min_views`)."""
    m = maps[a]
    poses = np.stack([other.pose for other in maps])
    neighbours = max(CONSISTENCY_NEIGHBOURS, min_views)
    cos_limit = np.cos(np.radians(normal_deg))
    z = np.asarray(depth, dtype=np.float64)
    world = pixels_to_world(u, v, z, m.K, m.pose)
    normals_world = np.asarray(normal, dtype=np.float64) @ m.pose[:3, :3].T if normal is not None else None
    count = np.zeros(len(z), dtype=np.int64)
    distance = np.linalg.norm(poses[:, :3, 3] - m.pose[:3, 3], axis=1)
    distance[a] = np.inf
    for b in np.argsort(distance)[:neighbours]:
        if not np.isfinite(distance[b]):
            continue
        other = maps[int(b)]
        ub, vb, zb = project_points(world, other.K, other.pose)
        front = zb > 1e-3
        zs = np.where(front, zb, 1.0)
        oh, ow = other.depth.shape
        inside = front & (ub >= 0) & (ub < ow) & (vb >= 0) & (vb < oh)
        col = np.clip(np.floor(ub).astype(np.int64), 0, ow - 1)
        row = np.clip(np.floor(vb).astype(np.int64), 0, oh - 1)
        found = np.where(inside, other.depth[row, col], 0.0).astype(np.float64)
        # Only points whose depth in the other view is near what it found there can agree (a loose bound:
        # the exact test is in this view, whose axis may be turned from the other's), so the rest of the
        # test runs on those alone.
        near = np.flatnonzero(inside & (found > 0) & (np.abs(found - zb) <= NEAR_FACTOR * relative_depth * zs))
        if len(near) == 0:
            continue
        col, row, found = col[near], row[near], found[near]
        # The other map's point at that pixel, back in this view.
        ua, va, zback = project_points(pixels_to_world(col, row, found, other.K, other.pose), m.K, m.pose)
        reprojected = np.hypot(ua - (u[near] + 0.5), va - (v[near] + 0.5))
        agree = (zback > 1e-6) & (np.abs(zback - z[near]) <= relative_depth * z[near]) & (reprojected <= reprojection_px)
        if normals_world is not None and other.normal is not None:
            other_normals = other.normal[row, col].astype(np.float64) @ other.pose[:3, :3].T
            agree &= np.sum(normals_world[near] * other_normals, axis=1) >= cos_limit
        count[near] += agree
    return count


# Pixels: a neighbour 6 px away is past the window's half-width (4), across a fattened edge. On SUN3D's
# maps (3, 6) adopts as well as (2, 4, 6) (within 5 % 0.660 either way) at half the time.
OFFSET_RADII = (3, 6)
MIN_CHANGE = 0.02  # a neighbour's plane within 2 % of the depth is the same surface: not a candidate
MIN_FACING = 0.1  # the neighbour's plane must face this pixel's ray (|cos| above this) to give it a depth
SAME_PLANE_DEPTH = 0.005  # two neighbours' planes within 0.5 % at the pixel...
SAME_PLANE_COS = float(np.cos(np.radians(5.0)))  # ...and 5 deg of each other are one candidate

_DIRECTIONS = [(dy, dx) for dy in (-1, 0, 1) for dx in (-1, 0, 1) if (dy, dx) != (0, 0)]


def candidate_offsets(radii: Sequence[int] = OFFSET_RADII) -> list[tuple[int, int]]:
    """(dy, dx) of the neighbours tried, nearest first, so that a tie goes to the nearest."""
    return [(dy * r, dx * r) for r in radii for dy, dx in _DIRECTIONS]


def neighbour_planes(m: DepthMap, v: np.ndarray, u: np.ndarray, offsets: Sequence[tuple[int, int]]
                     ) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """The planes of the neighbours at `offsets` (O of them) of map `m`'s pixels at rows v, columns u
    (N each), as candidates for those pixels: depths (O, N) where each plane meets the pixel's ray,
    its normals (O, N, 3), and which are worth trying (O, N) bool: inside the image, with a depth, the
    plane facing the ray, not the pixel's own surface (within MIN_CHANGE) and not a plane a nearer
    neighbour offers already."""
    assert m.normal is not None
    h, w = m.depth.shape
    K_inv = np.linalg.inv(m.K)
    depth = m.depth[v, u].astype(np.float64)
    rays = np.stack([u + 0.5, v + 0.5, np.ones(len(v))], axis=1) @ K_inv.T  # (N, 3), z = 1
    candidates, normals, tried = [], [], []
    for dy, dx in offsets:
        vn, un = v + dy, u + dx
        inside = (vn >= 0) & (vn < h) & (un >= 0) & (un < w)
        vn, un = np.clip(vn, 0, h - 1), np.clip(un, 0, w - 1)
        neighbour_depth = m.depth[vn, un].astype(np.float64)
        normal = m.normal[vn, un].astype(np.float64)
        neighbour_rays = np.stack([un + 0.5, vn + 0.5, np.ones(len(vn))], axis=1) @ K_inv.T
        # The neighbour's plane n . X = n . P meets this pixel's ray r (z = 1) at depth (n . P) / (n . r).
        facing = np.sum(normal * rays, axis=1)
        faces = np.abs(facing) > MIN_FACING * np.linalg.norm(rays, axis=1)
        candidate = np.where(faces, np.sum(normal * neighbour_rays, axis=1) * neighbour_depth
                             / np.where(faces, facing, 1.0), 0.0)
        worth = inside & (neighbour_depth > 0) & (candidate > 0) & (np.abs(candidate - depth) > MIN_CHANGE * depth)
        # A plane a nearer neighbour already offered (most of a wall's neighbours share one) is not tried
        # again: the checks cost in proportion to the candidates.
        for earlier, earlier_normal, earlier_tried in zip(candidates, normals, tried):
            worth &= ~(earlier_tried & (np.abs(candidate - earlier) <= SAME_PLANE_DEPTH * candidate)
                       & (np.sum(normal * earlier_normal, axis=1) >= SAME_PLANE_COS))
        candidates.append(candidate)
        normals.append(normal)
        tried.append(worth)
    return np.stack(candidates), np.stack(normals), np.stack(tried)


def adopt_confirmed_planes(maps: list[DepthMap], radii: Sequence[int] = OFFSET_RADII, workers: int = 1) -> list[int]:
    """Replace, in place, each unconfirmed depth of each map (with normals) by the depth of the
    neighbouring plane that the most other maps confirm; its normal goes with it. Returns how many
    depths of each map changed. `workers`: maps checked at once (threads); the result does not depend on it."""
    if len(maps) < 2:
        return [0] * len(maps)
    offsets = candidate_offsets(radii)

    def unconfirmed_of(a: int) -> tuple[np.ndarray, np.ndarray]:
        m = maps[a]
        v, u = np.nonzero(m.depth > 0)
        own = confirmations_at(maps, a, v, u, m.depth[v, u], m.normal[v, u] if m.normal is not None else None)
        return v[own == 0], u[own == 0]

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:  # numpy lets go of the GIL on whole arrays
        unconfirmed = list(pool.map(unconfirmed_of, range(len(maps))))
    trusted = []  # each map with only its confirmed depths: those vouch for a neighbour's plane
    for m, (v, u) in zip(maps, unconfirmed):
        depth = m.depth.copy()
        depth[v, u] = 0.0
        trusted.append(replace(m, depth=depth))

    def change_of(a: int) -> tuple[np.ndarray, np.ndarray, np.ndarray, np.ndarray]:
        m = maps[a]
        v, u = unconfirmed[a]
        if m.normal is None or len(v) == 0:
            return np.zeros(0, np.int64), np.zeros(0, np.int64), np.zeros(0), np.zeros((0, 3))
        candidate_all, normal_all, tried_all = neighbour_planes(m, v, u, offsets)
        # All candidates of the map in one check: (offsets, N), the nearest offset first.
        which, pixel = np.nonzero(tried_all)
        counts = np.zeros(tried_all.shape, np.int64)
        counts[which, pixel] = confirmations_at(trusted, a, v[pixel], u[pixel], candidate_all[which, pixel],
                                                normal_all[which, pixel])
        best = np.argmax(counts, axis=0)  # the first (nearest) of the most confirmed
        take = counts[best, np.arange(len(v))] > 0
        return (v[take], u[take], candidate_all[best[take], np.flatnonzero(take)],
                normal_all[best[take], np.flatnonzero(take)])

    with ThreadPoolExecutor(max_workers=max(1, workers)) as pool:
        changes = list(pool.map(change_of, range(len(maps))))
    for m, (v, u, depth, normal) in zip(maps, changes):
        if len(v):
            m.depth[v, u] = depth.astype(m.depth.dtype)
            m.normal[v, u] = normal.astype(m.normal.dtype)
    return [len(v) for v, _, _, _ in changes]
