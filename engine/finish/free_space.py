"""What the depth maps say about points in space: seen there, seen through (free space) or hidden.

Every view with a depth map votes on a point it frames: the depth at its pixel equals the point's
depth (within a margin) -> the view *saw* a surface there; it is farther -> the view *saw through*
the point, so the point is free space (an open door, a window, air in front of a wall); it is nearer
-> the point was *hidden* behind something (the wall behind a wardrobe). No depth at the pixel, or
the point outside the image: no vote. The finishing stage reads these votes to bound planes (a wall
is not extended where views saw through it), to close holes (only where no view saw through) and to
judge pieces (a piece in free space or seen by too few views is dropped). A view that meets a plane at
a grazing angle does not hide that plane's points (`view_votes(plane_normal=...)`): what stands in
front of them along the ray is mostly the plane's own surface.

The stereo method's own depth maps are the views (`engine.stereo.depth_maps.DepthMap` has the fields);
a method without depth maps uses the mesh's own depth from the keyframes (`mesh_depth_views`).
Pixel convention as the fusion's: pixel (i, j) covers u in [j, j + 1), v in [i, i + 1).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Optional, Protocol, Sequence

import numpy as np

from ..geometry.cameras import pixels_to_world, scale_intrinsics
from ..mesh_io import Mesh
from ..photo_sampling import occlusion_depth, points_in_view

# Depths agree within this many metres plus this share of the depth: stereo depth on plain walls is
# off by a few percent (docs/experiments.md, SUN3D: median 6-7 % on refined poses). A map that knows
# its own accuracy (a phone's LiDAR, engine/stereo/sensor_maps.py) carries a tighter `agreement`.
AGREE_METRES = 0.08
AGREE_RELATIVE = 0.03


class DepthView(Protocol):
    """A depth map and its camera: depth (h, w) float32 planar metres (0 or inf = none), K (3, 3) in
    pixels of `depth`, pose (4, 4) camera-to-world; agreement (metres, share of the depth): how far
    from its depth a point may lie and still be the surface it saw, None for stereo's
    (AGREE_METRES, AGREE_RELATIVE)."""

    depth: np.ndarray
    K: np.ndarray
    pose: np.ndarray
    agreement: Optional[tuple[float, float]]


@dataclass
class PlainDepthView:
    """A DepthView made here (from a rendered mesh)."""

    depth: np.ndarray
    K: np.ndarray
    pose: np.ndarray
    agreement: Optional[tuple[float, float]] = None


@dataclass
class Votes:
    """Per point (N,) int32 counts of views that saw a surface there, saw through it, or saw it hidden,
    and of views whose image frames it at all (with a depth at its pixel or not: a plain wall that
    stereo could not match is still in view)."""

    seen: np.ndarray
    through: np.ndarray
    hidden: np.ndarray
    in_view: np.ndarray

    @property
    def framed(self) -> np.ndarray:
        """(N,) views with a depth where the point projects (any of the three)."""
        return self.seen + self.through + self.hidden

    def free(self, min_votes: int = 2) -> np.ndarray:
        """(N,) bool: free space by the evidence: at least `min_votes` views saw through the point, and
        more saw through than saw a surface there (one stray depth behind a wall does not open it)."""
        return (self.through >= min_votes) & (self.through > self.seen)

    def contradicted(self) -> np.ndarray:
        """(N,) bool: surface there is contradicted: a view saw through the point, and fewer than three
        times as many saw a surface there or something in front of it (a stray far depth is outvoted)."""
        return (self.through > 0) & (3 * self.through > self.seen + self.hidden)


# A view that sees a plane's point at less than this angle to the plane says nothing about it: along a
# corridor wall, the wall itself hides the open doorway at its end from every camera down the leg
# (the 3D Scanner App corridor: 14 such views against the 3 that saw through it closed the corner).
MIN_GRAZING_DEG = 15.0


def view_votes(points: np.ndarray, views: Sequence[DepthView], plane_normal: Optional[np.ndarray] = None) -> Votes:
    """The votes of `views` on world `points` (N, 3): see the module doc; a view's depth agrees with a
    point's within its `agreement` (metres + share x depth). With `plane_normal` (3,) the points lie on
    that plane, and a view whose ray meets it at under MIN_GRAZING_DEG casts no vote there (it still
    frames the point: `in_view`)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    min_sine = np.sin(np.radians(MIN_GRAZING_DEG))
    seen = np.zeros(len(points), np.int32)
    through = np.zeros(len(points), np.int32)
    hidden = np.zeros(len(points), np.int32)
    in_view = np.zeros(len(points), np.int32)
    for view in views:
        depth = np.asarray(view.depth)
        h, w = depth.shape
        ids, u, v, z = points_in_view(points, view.K, view.pose, (w, h))
        in_view[ids] += 1
        d = depth[np.floor(v).astype(np.int64), np.floor(u).astype(np.int64)].astype(np.float64)
        valid = (d > 0) & np.isfinite(d)
        grazing = np.zeros(len(ids), bool)
        if plane_normal is not None:
            rays = points[ids] - np.asarray(view.pose, np.float64)[:3, 3]
            grazing = np.abs(rays @ plane_normal) < min_sine * np.linalg.norm(rays, axis=1)
        ids, z, d, grazing = ids[valid], z[valid], d[valid], grazing[valid]
        agree_metres, agree_relative = view.agreement or (AGREE_METRES, AGREE_RELATIVE)
        margin = agree_metres + agree_relative * z
        seen[ids[np.abs(d - z) <= margin]] += 1
        through[ids[d > z + margin]] += 1
        hidden[ids[(d < z - margin) & ~grazing]] += 1
    return Votes(seen, through, hidden, in_view)


def mesh_depth_views(mesh: Mesh, Ks: np.ndarray, poses: np.ndarray, image_size: tuple[int, int]) -> list[PlainDepthView]:
    """The mesh's own depth maps from cameras (Ks (C, 3, 3) in pixels of `image_size` = (w, h), poses
    (C, 4, 4)), at the occlusion test's resolution: the free space of a method without depth maps (the
    mesh is all it knows; inf where the mesh is not hit casts no vote)."""
    views = []
    w, h = image_size
    for K, pose in zip(Ks, poses):
        depth = occlusion_depth(mesh, K, pose, (w, h))
        dh, dw = depth.shape
        views.append(PlainDepthView(depth, scale_intrinsics(np.asarray(K, np.float64), (w, h), (dw, dh)),
                                    np.asarray(pose, np.float64)))
    return views


def surface_offsets(points: np.ndarray, normal: np.ndarray, offset: float, views: Sequence[DepthView],
                    reach: float) -> np.ndarray:
    """(N,) float: where the depth maps put the surface near each of `points` (N, 3) on the plane
    n . x = offset (unit `normal` (3,)): the median, over the views whose surface along the ray lies
    within `reach` m of the plane, of that surface's signed distance from the plane (positive on the
    normal's side); NaN where fewer than two views say. The maps' median is steadier than the mesh they
    make: stereo's crumple is their disagreement, a recess (a bookcase's shelves) their agreement."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    point_ids, distances = [], []
    for view in views:
        depth = np.asarray(view.depth)
        h, w = depth.shape
        ids, u, v, z = points_in_view(points, view.K, view.pose, (w, h))
        d = depth[np.floor(v).astype(np.int64), np.floor(u).astype(np.int64)].astype(np.float64)
        valid = (d > 0) & np.isfinite(d)
        ids, z, d = ids[valid], z[valid], d[valid]
        # The view's surface on the point's ray is at (d / z) of the way from the camera: its plane
        # distance is (n . C - offset) (1 - d / z).
        centre_distance = float(np.asarray(view.pose, np.float64)[:3, 3] @ normal - offset)
        distance = centre_distance * (1.0 - d / z)
        near = np.abs(distance) <= reach
        point_ids.append(ids[near])
        distances.append(distance[near])
    median = np.full(len(points), np.nan)
    if not point_ids:
        return median
    ids, distance = np.concatenate(point_ids), np.concatenate(distances)
    order = np.lexsort((distance, ids))
    ids, distance = ids[order], distance[order]
    counts = np.bincount(ids, minlength=len(points))
    starts = np.concatenate([[0], np.cumsum(counts)[:-1]])
    said = counts >= 2
    low = distance[starts[said] + (counts[said] - 1) // 2]
    high = distance[starts[said] + counts[said] // 2]
    median[said] = 0.5 * (low + high)
    return median


# A glossy floor mirrors the ceiling's lights and the walls: stereo matches the mirror image, a depth
# below the floor, and every such depth votes that its view saw through the floor, so the finishing
# would not close the floor there (the 3D Scanner App corridor: 1.5 % of its stereo depths lie more
# than 10 cm below its floor, and 4,156 floor cells stayed open). A room's floor was found with little
# surface below it, so a depth below it, seen through the room's own floor, is a reflection, not a view
# through it: such depths are left out of the votes. Seen past the floor's edge (through a door, down a
# stair) it stays. Only while they are a small share of all depths: a floor with much seen below it (a
# wrong floor, a gallery over a hall) keeps every vote.
REFLECTION_MARGIN = 0.10  # m below the floor plane
REFLECTION_MAX_SHARE = 0.05  # of all depths


@dataclass
class Reflections:
    """What `without_reflections` found: depths below the floor seen through it, of how many depths, and
    whether they were left out."""

    below: int
    depths: int
    left_out: bool

    def to_dict(self) -> dict:
        return {"below_floor_depths": self.below, "depths": self.depths, "left_out": self.left_out}


def without_reflections(views: Sequence[DepthView], height_over_floor: Callable[[np.ndarray], np.ndarray],
                        on_floor: Callable[[np.ndarray], np.ndarray], margin: float = REFLECTION_MARGIN,
                        max_share: float = REFLECTION_MAX_SHARE) -> tuple[list[DepthView], Reflections]:
    """`views` with their depths more than `margin` below the floor taken out (copies; the views given
    are not changed) where the ray to them crosses the floor plane on the floor, when those are at most
    `max_share` of all depths; else the views as given.
    height_over_floor: (N, 3) world points -> (N,) signed height over the floor plane; on_floor: (N, 3)
    points on the floor plane -> (N,) bool, whether the room's floor is there."""
    below_masks, below, total = [], 0, 0
    for view in views:
        depth = np.asarray(view.depth)
        has = np.isfinite(depth) & (depth > 0)
        v, u = np.nonzero(has)
        z = depth[v, u].astype(np.float64)
        pose = np.asarray(view.pose, np.float64)
        points = pixels_to_world(u, v, z, view.K, pose)
        height = height_over_floor(points)
        camera_height = float(height_over_floor(pose[None, :3, 3])[0])
        under = np.flatnonzero(height < -margin)
        mask = np.zeros(depth.shape, bool)
        if camera_height > 0 and len(under):
            # Where the ray from the camera to the point crosses the floor plane.
            share = camera_height / (camera_height - height[under])
            crossing = pose[:3, 3] + share[:, None] * (points[under] - pose[:3, 3])
            through_floor = under[on_floor(crossing)]
            mask[v[through_floor], u[through_floor]] = True
        below_masks.append(mask)
        below += int(mask.sum())
        total += len(z)
    left_out = 0 < below <= max_share * max(total, 1)
    if not left_out:
        return list(views), Reflections(below, total, False)
    kept: list[DepthView] = []
    for view, mask in zip(views, below_masks):
        depth = np.array(view.depth, copy=True)
        depth[mask] = 0.0
        kept.append(PlainDepthView(depth, view.K, view.pose, view.agreement))
    return kept, Reflections(below, total, True)
