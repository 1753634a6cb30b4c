"""Plane-aware finishing of a reconstructed room: the `finish` setting (off / clean / room).

Naive clean-up trades geometry away (docs/experiments.md, "A finished room"): dropping small pieces
throws real surface out with the dust, smoothing pulls walls off their planes. This uses the evidence
instead: the structural planes (`planes.py`), the depth maps' votes (`free_space.py`) and the cameras.

- clean: faces most views see through are carved (crumpled stereo in front of what the other views
  saw), surface behind a structural plane where the plane stands is dropped (nothing in the room sees
  through a wall except through its openings), pieces are dropped where the views do not support them
  (`_pieces_to_drop`: few vertices seen, floating in free space, or small and seen by too few views of
  a room whose floor and walls were found), and vertices within `tolerance` of a plane that face its way
  are moved onto it. Nothing is added.
- room: as clean, but each structural plane becomes one grid surface (cells of the voxel size) over
  the cells the surface covered, plus the cells no view saw through inside the plane's extent (bounded
  by the floor, ceiling and neighbouring walls, by what the photos framed, and by free space: a wall
  does not close an open door or a window seen through; an added stretch touches seen surface). Its
  faces replace the mesh's own near the plane, and what is left of the mesh within two tolerances of a
  plane where it stands (crumpled wall the tolerance did not reach) goes with them; furniture and
  anything off the planes stays as it was. Added faces are marked: the vertex attribute ADDED is 1 on
  them (their vertices are their own, not shared with seen faces).

A plane is applied only where the evidence agrees (issue 43): each grid follows where the surface
stands (`local_shift`: drift and slope put a real floor centimetres off any one plane), surface off it
by more than its noise over a patch is relief and stays (`flat_band`, RELIEF_MIN_AREA), and surface
behind a plane that cameras behind the plane saw where it is stays and refutes the plane there
(`_seen_from_behind`: the next leg of a U-shaped corridor), and so does surface behind a wall that
views saw through the wall's openings (`_seen_through_openings`: a recess, the floor past a doorway);
only surface behind a plane that no view supports there goes.

Input and output are `engine.mesh_io.Mesh` in the engine's world (metres, Z up, or tilted: `planes.room_up`); colours and evidence
are attached after finishing by the reconstruction, so only positions, faces and ADDED come out.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Any, Callable, Optional, Sequence

import numpy as np
from scipy import ndimage
from scipy.spatial import cKDTree

from ..mesh_io import Mesh
from ..meshops import compact, face_pieces, keep_faces, vertex_normals
from ..observation import ADDED  # vertex attribute: 1 on faces the finishing added (not seen), 0 elsewhere
from .free_space import DepthView, Votes, view_votes, without_reflections
from .furniture import WINDOW as FURNITURE_WINDOW
from .furniture import find_furniture_planes, furniture_grid
from .grid import RELIEF_MIN_AREA, PlaneGrid, flat_band, grid_mesh, local_shift, stretches_of_area
from .modes import FINISH_CLEAN, FINISH_MODES, FINISH_OFF, FINISH_ROOM
from .planes import CEILING, FLOOR, WALL, StructuralPlane, face_geometry, find_structural_planes, floor_up, room_up


FLOOR_REACH_QUANTILE = 0.99  # of the seen floor's distances from the nearest camera: how far floor is added
HIDDEN_OUTVOTED = 3  # views that saw a plane's cell for each one that saw something in front of it
SNAP_DISTANCE = 0.6  # m: a plane's observed end this near a neighbouring wall is taken to that wall
SUPPORTED_SHARE = 0.3  # of a piece's vertices seen by `min_views` views: the piece is supported
VIEWS_PER_MIN_VIEW = 18  # depth maps per view a piece must be seen by
VIEWS_PER_SMALL_PIECE_VIEW = 6  # depth maps per view a small piece must be seen by
SMALL_PIECE_AREA = 0.25  # m^2: a piece this small needs more views (the surface metrics' floater size)
SUPPORTED_VERTICES = 64  # or this many such vertices (a 30 cm patch at 4 cm voxels seen twice)
FLATTEN_COS = 0.5  # a vertex is flattened onto a plane only when its normal is within 60 deg of the plane's
ABSORB_TOLERANCE_FACTOR = 2.0  # pieces within this many tolerances of a plane, where it stands, are the plane's
ABSORBED_SHARE = 0.8  # of a piece's area
FLOOR_UP_MAX_TURN_DEG = 5.0  # the floor's normal refines the horizon's up by at most this,
FLOOR_UP_MIN_AGREEMENT = 0.3  # and only when this share of its area agrees with it (`planes.floor_up`)
EXTENT_PERCENTILE = 0.5  # % of a plane's surface cut at each end of its extent (stray faces)
BLIND_REACH = 3.0  # camera heights: the farthest a camera's blind spot on the floor (or ceiling) reaches
# A real room's planes are not one plane across the room: tracking drift and a floor's own slope put the
# surface a few cm off any single plane (the 3D Scanner App corridor: its floor within -2 .. +3.4 cm of
# one plane, its walls -7 .. +7 cm, per metre-square cell), and flattening onto the single plane moved
# them by as much. So each grid follows the surface's own offset from its plane, smoothed over this many
# metres (a sensor's ripples and stereo's crumples are shorter; drift and slope are longer).
SHIFT_SMOOTHING = 0.5  # m: the Gaussian's sigma
SHIFT_ROUNDS = 3  # the shifted surface is found again this many times (and reaches as many tolerances off)
FURNITURE_MIN_HEIGHT = 0.1  # m over the floor: surface higher than this (and below the cameras) is furniture over it


@dataclass
class FinishOptions:
    """tolerance: m from a structural plane within which surface is the plane (None: 2 voxels, at
    least 6 cm). min_views: depth maps that must see a piece for it to stay; small_piece_views: those
    that must see a small piece (under SMALL_PIECE_AREA) of a room whose structure was found (None:
    scaled with the number of depth maps, one per VIEWS_PER_MIN_VIEW / VIEWS_PER_SMALL_PIECE_VIEW).
    cell: the plane grid's cell in m (None: the voxel size). min_plane_area: m^2 of surface a plane needs.
    refuting_views: depth maps that must see surface (each of a face's vertices) behind a plane for it to
    stay and refute the plane there."""

    tolerance: Optional[float] = None
    min_views: Optional[int] = None
    small_piece_views: Optional[int] = None
    cell: Optional[float] = None
    min_plane_area: float = 0.3
    refuting_views: int = 2
    furniture: bool = True


@dataclass
class FinishResult:
    mesh: Mesh
    planes: list[StructuralPlane]
    stats: dict[str, Any] = field(default_factory=dict)


def _robust_range(values: np.ndarray, weights: np.ndarray) -> tuple[float, float]:
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    cut = EXTENT_PERCENTILE / 100 * cumulative[-1]
    return float(values[order][np.searchsorted(cumulative, cut)]), float(values[order][np.searchsorted(cumulative, cumulative[-1] - cut)])


def _snapped(low: float, high: float, stops: list[float]) -> tuple[float, float]:
    """The range's ends moved to the nearest `stops` (where neighbouring walls cross it) within SNAP_DISTANCE."""
    for stop in stops:
        if abs(stop - low) <= SNAP_DISTANCE and stop < high:
            low = stop
        elif abs(stop - high) <= SNAP_DISTANCE and stop > low:
            high = stop
    return low, high


def _wall_stops(plane: StructuralPlane, axis: int, walls: Sequence[StructuralPlane]) -> list[float]:
    """Where the other walls cross `plane`'s in-plane axis `axis` (0 = u), as coordinates along it."""
    stops = []
    direction = plane.axes[axis]
    for wall in walls:
        if wall is plane or abs(wall.normal @ direction) < 0.5:
            continue
        # wall.normal . (plane point + t * direction) = wall.offset, from the plane's origin point.
        stops.append(float((wall.offset - wall.normal @ (plane.normal * plane.offset)) / (wall.normal @ direction)))
    return stops


def plane_grid(plane: StructuralPlane, planes: Sequence[StructuralPlane], centroids: np.ndarray, areas: np.ndarray,
               normals: np.ndarray, distance: np.ndarray, tolerance: float, cell: float, views: Sequence[DepthView],
               fill: bool) -> Optional[PlaneGrid]:
    """The cells of one structural plane (see the module doc); None when no surface lies on it.

    centroids (F, 3), areas (F,), normals (F, 3): the mesh's faces; distance (F,) their signed distance
    to the plane."""
    near = np.abs(distance) <= tolerance
    if not near.any():
        return None
    coords = plane.to_plane(centroids[near])
    walls = [p for p in planes if p.kind == WALL]
    floor = next((p for p in planes if p.kind == FLOOR), None)
    ceiling = next((p for p in planes if p.kind == CEILING), None)
    (a0, a1), (b0, b1) = _robust_range(coords[:, 0], areas[near]), _robust_range(coords[:, 1], areas[near])
    a0, a1 = _snapped(a0, a1, _wall_stops(plane, 0, walls))
    if plane.kind == WALL:
        if floor is not None:
            b0 = floor.offset
        if ceiling is not None:
            b1 = -ceiling.offset
    else:
        b0, b1 = _snapped(b0, b1, _wall_stops(plane, 1, walls))
    origin = np.array([a0, b0])
    shape = (max(1, int(np.ceil((a1 - a0) / cell))), max(1, int(np.ceil((b1 - b0) / cell))))
    grid = PlaneGrid(plane, origin, cell, np.zeros(shape, bool), np.zeros(shape, bool), np.zeros(shape, bool),
                     np.zeros(shape, bool), np.zeros(shape), np.zeros(shape, bool), tolerance)
    # Where the surface stands (`shift`), found from the faces within the tolerance of it: first of the
    # plane, then of the shifted surface, which reaches a wall drifting further off as it goes on.
    reach = np.flatnonzero(np.abs(distance) <= SHIFT_ROUNDS * tolerance)
    i, j, inside = grid.cells_of(plane.to_plane(centroids[reach]))
    # Only faces turned the plane's way say where it stands (a cabinet side beside a wall does not).
    facing = normals[reach] @ plane.normal > FLATTEN_COS
    window = tolerance
    on = inside & (np.abs(distance[reach]) <= window)
    for round_ in range(SHIFT_ROUNDS):
        grid.shift = local_shift(shape, i[on & facing], j[on & facing], distance[reach][on & facing],
                                 areas[reach][on & facing], SHIFT_SMOOTHING / cell)
        residual = distance[reach] - grid.shift[i, j]
        if round_ == SHIFT_ROUNDS - 2:
            # The last round keeps only surface within the plane's own noise (its faces' spread about the
            # shifted surface): the mode, not a mean pulled by a door frame or a recess beside it.
            grid.band = flat_band(residual[on & facing], tolerance)
            window = grid.band
        on = inside & (np.abs(residual) <= window)
    near = inside & (np.abs(residual) <= tolerance)
    grid.observed[i[near], j[near]] = True
    # Surface near the plane but off it by more than its noise, over a patch, is relief (a door frame,
    # a recess, a skirting board): kept as it is, and the plane adds no cell over it. Scattered cells
    # off it are crumpled stereo, which the plane replaces.
    off_band = np.zeros(shape, bool)
    off_band[i[near & ~on], j[near & ~on]] = True
    off_band[i[on], j[on]] = False
    grid.relief = stretches_of_area(off_band, cell, RELIEF_MIN_AREA)
    grid.observed &= ~grid.relief
    # Faces of the 4 cm marching cubes leave single empty cells between their centroids: close them.
    grid.observed = ndimage.binary_closing(grid.observed, structure=np.ones((3, 3), bool), border_value=0) | grid.observed
    centres = grid.centres()
    inside_walls = np.ones(len(centres), bool)
    if plane.kind != WALL:  # the floor and ceiling stop at the walls, where a wall stands
        cameras = np.stack([np.asarray(v.pose, np.float64)[:3, 3] for v in views]) if views else np.zeros((0, 3))
        # ... unless the walk went on past it (through its door): a cell whose nearest camera stands on
        # the wall's far side too is floor the walk crossed (the 3D Scanner App corridor's connecting
        # leg lost its far half, 4.8 m of floor, to a door frame across it).
        camera_distance, nearest = (cKDTree(plane.to_plane(cameras)).query(plane.to_plane(centres)) if len(cameras)
                                    else (None, None))
        for wall in walls:
            along = wall.to_plane(centres)[:, 0]
            # The wall's own surface (faces turned its way), not the floor and ceiling along its line:
            # in an L-shaped room the inner wall's line crosses the other leg's floor.
            own = (np.abs(wall.distance(centroids)) <= tolerance) & (normals @ wall.normal > FLATTEN_COS)
            wall_coords = wall.to_plane(centroids[own])[:, 0]
            if len(wall_coords) == 0:
                continue
            span = np.percentile(wall_coords, 1) - SNAP_DISTANCE, np.percentile(wall_coords, 99) + SNAP_DISTANCE
            beyond = (wall.distance(centres) < -cell) & (along >= span[0]) & (along <= span[1])
            if nearest is not None:
                beyond &= wall.distance(cameras[nearest]) > 0
            inside_walls &= ~beyond
    grid.observed &= inside_walls.reshape(shape)
    votes: Votes = view_votes(centres, views, plane_normal=plane.normal)
    grid.free = votes.free().reshape(shape)
    grid.open = votes.contradicted().reshape(shape)
    grid.keep = grid.observed.copy()
    if fill:
        # In some photo, and no view saw through it: a stereo gap on a plain wall or a stretch hidden
        # behind furniture closes; an open door or a window seen through stays open.
        fillable = (votes.in_view >= 1) & ~votes.contradicted() & inside_walls
        if plane.kind in (FLOOR, CEILING):
            # The floor a camera stood over (and the ceiling it stood under) is in no photo near its foot,
            # yet walked on: closed too, where no view saw through it.
            fillable |= beneath_cameras(plane, centres, views) & ~votes.contradicted() & inside_walls
            # A stretch some view saw something in front of is another room's, behind a wall (the inside
            # of a U-shaped corridor, whose inner walls are no room-box planes), unless something of
            # this room stands over it below the cameras (the floor under a table or a chair closes), or
            # three times as many views saw the floor itself there: a stray depth in front of a glossy
            # floor's dip left 4,300 holes along the corridor's walk, each seen by 8 views (median).
            fillable &= ((votes.hidden == 0) | (votes.seen >= HIDDEN_OUTVOTED * votes.hidden)
                         | under_furniture(grid, centroids, views))
        if plane.kind == FLOOR and camera_distance is not None and grid.observed.any():
            # Floor further from the walk than nearly all the floor it saw is floor it did not see: the
            # offices inside the corridor's U, behind glass fronts stereo leaves open (280 m^2 were laid).
            reach = np.quantile(camera_distance[grid.observed.ravel()], FLOOR_REACH_QUANTILE)
            fillable &= camera_distance <= reach
        grid.keep |= fillable.reshape(shape)
        # Closing holes, not inventing surface: an added stretch must touch surface that was seen.
        labels, count = ndimage.label(grid.keep)
        seen_labels = np.unique(labels[grid.observed & grid.keep])
        grid.keep &= np.isin(labels, seen_labels[seen_labels > 0]) & ~grid.relief
    return grid


def floor_extent(floor: StructuralPlane, centroids: np.ndarray, normals: np.ndarray, tolerance: float
                 ) -> Callable[[np.ndarray], np.ndarray]:
    """A test of points on the floor plane (N, 3) -> (N,) bool: within the rectangle, in the plane's axes,
    of the faces lying on it and facing up (`centroids`, `normals` (F, 3)): where the room's floor is,
    not past a wall's door."""
    on = (np.abs(floor.distance(centroids)) <= tolerance) & (normals @ floor.normal > FLATTEN_COS)
    if not on.any():
        return lambda points: np.zeros(len(points), bool)
    uv = floor.to_plane(centroids[on])
    low, high = uv.min(axis=0), uv.max(axis=0)

    def inside(points: np.ndarray) -> np.ndarray:
        at = floor.to_plane(points)
        return np.all((at >= low) & (at <= high), axis=1)

    return inside


def over_floor(grid: PlaneGrid, floor: PlaneGrid, margin_cells: int = 2) -> np.ndarray:
    """(A, B) bool: which of `grid`'s cells lie over the floor's finished cells (grown by `margin_cells`)."""
    footprint = ndimage.binary_dilation(floor.keep, iterations=margin_cells)
    i, j, inside = floor.cells_of(floor.plane.to_plane(grid.centres()))
    return (inside & footprint[i, j]).reshape(grid.keep.shape)


def under_furniture(grid: PlaneGrid, centroids: np.ndarray, views: Sequence[DepthView]) -> np.ndarray:
    """(A*B,) bool, the grid's cells raveled: surface (face centroids (F, 3)) stands over the cell (or
    a neighbouring one) between FURNITURE_MIN_HEIGHT above the plane and the cameras' median height
    over it: a table, a chair, a cabinet. Only a floor has furniture over it; any other plane none."""
    plane = grid.plane
    over = np.zeros(grid.keep.shape, bool)
    if plane.kind != FLOOR or not views:
        return over.ravel()
    camera_height = float(np.median(plane.distance(np.stack([np.asarray(v.pose, np.float64)[:3, 3] for v in views]))))
    height = plane.distance(centroids)
    standing = (height > FURNITURE_MIN_HEIGHT) & (height < camera_height)
    i, j, inside = grid.cells_of(plane.to_plane(centroids[standing]))
    over[i[inside], j[inside]] = True
    return ndimage.binary_dilation(over, iterations=1).ravel()


def beneath_cameras(plane: StructuralPlane, points: np.ndarray, views: Sequence[DepthView],
                    max_reach: float = BLIND_REACH) -> np.ndarray:
    """(N,) bool: which points (N, 3) on a floor or ceiling plane lie in some camera's blind spot on it:
    nearer the camera's foot (its centre projected onto the plane) than any ray through its photo's
    border meets the plane. A photo held level frames the floor from about 2.3 camera heights away
    (a 47 deg vertical field of view), so a walk through a room sees none of the floor it walked on.
    The reach is at most `max_reach` camera heights (a camera facing away from the plane)."""
    points = np.asarray(points, np.float64).reshape(-1, 3)
    inside = np.zeros(len(points), bool)
    for view in views:
        pose = np.asarray(view.pose, np.float64)
        centre = pose[:3, 3]
        height = float(plane.distance(centre[None])[0])
        if height <= 0:
            continue
        foot = centre - height * plane.normal
        h, w = np.asarray(view.depth).shape
        edge_u, edge_v = np.linspace(0, w, 17), np.linspace(0, h, 13)
        border = np.concatenate([np.stack([edge_u, np.zeros(17)], 1), np.stack([edge_u, np.full(17, h)], 1),
                                 np.stack([np.zeros(13), edge_v], 1), np.stack([np.full(13, w), edge_v], 1)])
        rays = (pose[:3, :3] @ np.linalg.solve(np.asarray(view.K, np.float64), np.c_[border, np.ones(len(border))].T)).T
        towards = rays @ plane.normal  # < 0: the ray heads for the plane
        hits = centre + rays[towards < -1e-9] * (height / -towards[towards < -1e-9])[:, None]
        reach = min(float(np.min(np.linalg.norm(hits - foot, axis=1), initial=np.inf)), max_reach * height)
        inside |= np.linalg.norm(points - foot, axis=1) < reach
    return inside


def typical_support(seen: np.ndarray, faces: np.ndarray) -> int:
    """The median, at least 1, of `seen` (V,) (views that saw each vertex) over the vertices `faces` (F, 3)
    use: how many views the mesh's typical surface is seen by."""
    if len(faces) == 0:
        return 1
    used = np.zeros(len(seen), bool)
    used[faces.ravel()] = True
    return max(1, int(np.median(seen[used])))


def _seen_from_behind(vertices: np.ndarray, faces: np.ndarray, behind: np.ndarray, plane: StructuralPlane,
                      views: Sequence[DepthView], min_views: int) -> np.ndarray:
    """(F,) bool: which `behind` (F,) faces (vertices (V, 3), faces (F, 3)) behind `plane` are seen where
    they are, each vertex by `min_views` views, from cameras behind the plane too: surface the plane does
    not bound (the next leg of a U-shaped corridor beyond a wall of this one), which refutes it there.
    Seen only from the room's side, it would have been seen through the plane where the plane stands:
    stereo's debris (or an opening, whose cells are open already)."""
    from_behind = [view for view in views if plane.distance(np.asarray(view.pose)[None, :3, 3])[0] < 0]
    seen = np.zeros(len(faces), bool)
    if not from_behind or not behind.any():
        return seen
    used, inverse = np.unique(faces[behind], return_inverse=True)
    votes = view_votes(vertices[used], from_behind).seen
    seen[behind] = (votes[inverse.reshape(-1, 3)] >= min_views).all(axis=1)
    return seen


def _seen_through_openings(vertices: np.ndarray, faces: np.ndarray, behind: np.ndarray, grid: PlaneGrid,
                           views: Sequence[DepthView], min_views: int) -> np.ndarray:
    """(F,) bool: which `behind` (F,) faces (vertices (V, 3), faces (F, 3)) behind a wall's grid are seen
    where they are, each vertex by `min_views` views from the room's side whose rays cross the plane in
    one of its openings (cells views saw through, grown by a cell): the floor of a recess or of the next
    room past a doorway that the wall's extent spans. `blocks` judges such surface by the cell straight
    in front of it, which is solid wall beside the opening; the views looked through the opening."""
    plane = grid.plane
    seen = np.zeros(len(faces), bool)
    in_front = [view for view in views if plane.distance(np.asarray(view.pose, np.float64)[None, :3, 3])[0] > 0]
    if not in_front or not behind.any() or not grid.open.any():
        return seen
    used, inverse = np.unique(faces[behind], return_inverse=True)
    points = vertices[used]
    opening = ndimage.binary_dilation(grid.open, iterations=1)
    count = np.zeros(len(points), np.int32)
    for view in in_front:
        centre = np.asarray(view.pose, np.float64)[:3, 3]
        rays = points - centre
        towards = rays @ plane.normal  # < 0: the ray heads through the plane to the point behind it
        t = -plane.distance(centre[None])[0] / np.where(towards < -1e-9, towards, -1e-9)
        i, j, inside = grid.cells_of(plane.to_plane(centre + t[:, None] * rays))
        count += (view_votes(points, [view]).seen > 0) & (towards < -1e-9) & inside & opening[i, j]
    seen[behind] = (count[inverse.reshape(-1, 3)] >= min_views).all(axis=1)
    return seen


def _pieces_to_drop(mesh: Mesh, votes: Votes, min_views: int, small_min_views: int) -> tuple[np.ndarray, int, int]:
    """(drop (F,) bool, pieces, dropped pieces): a piece goes when few of its vertices are seen by
    `min_views` views (under SUPPORTED_SHARE of them and under SUPPORTED_VERTICES), when most of its
    vertices are seen through by more views than see them (it floats in free space), or when it is a
    small piece (under SMALL_PIECE_AREA) that fewer than `small_min_views` views see (the median of its
    vertices): a real small object is seen from many places, stereo's debris only by the few views that
    made it and their neighbours (measured on the demo room: docs/experiments.md, "A finished room")."""
    labels, sizes = face_pieces(mesh.faces, len(mesh.vertices))
    if len(sizes) == 0:
        return np.zeros(0, bool), 0, 0
    _, face_areas, _ = face_geometry(mesh.vertices, mesh.faces)
    area = np.bincount(labels, face_areas, minlength=len(sizes))
    face_seen = votes.seen[np.asarray(mesh.faces)].mean(axis=1)
    order = np.lexsort((face_seen, labels))  # faces by piece, then by how many views see them
    starts = np.searchsorted(labels[order], np.arange(len(sizes)))
    median_seen = face_seen[order][starts + (np.bincount(labels, minlength=len(sizes)) - 1) // 2]
    vertex_piece = np.zeros(len(mesh.vertices), np.int64)
    vertex_piece[mesh.faces.ravel()] = np.repeat(labels, 3)
    used = np.zeros(len(mesh.vertices), bool)
    used[mesh.faces.ravel()] = True
    count = np.bincount(vertex_piece[used], minlength=len(sizes)).astype(np.float64)
    supported = np.bincount(vertex_piece[used], (votes.seen[used] >= min_views).astype(np.float64), minlength=len(sizes))
    floating = np.bincount(vertex_piece[used], (votes.through[used] > votes.seen[used]).astype(np.float64), minlength=len(sizes))
    # A large surface seen well in part (a floor seen from afar) stays: enough of it is supported.
    drop_piece = (((supported < SUPPORTED_SHARE * count) & (supported < SUPPORTED_VERTICES)) | (floating > 0.5 * count)
                  | ((area < SMALL_PIECE_AREA) & (median_seen < small_min_views)))
    return drop_piece[labels], int(len(sizes)), int(drop_piece.sum())


def _pieces_absorbed(mesh: Mesh, grids: Sequence[PlaneGrid], band: float) -> tuple[np.ndarray, int]:
    """(drop (F,) bool, pieces dropped): the pieces left after the planes took their surface whose faces
    lie (ABSORBED_SHARE of them, by area) within `band` of a plane where the plane stands: crumpled
    wall surface the tolerance did not reach, which the plane's grid already shows."""
    if len(mesh.faces) == 0 or not grids:
        return np.zeros(len(mesh.faces), bool), 0
    centroids, areas, _ = face_geometry(mesh.vertices, mesh.faces)
    near = np.zeros(len(centroids), bool)
    for grid in grids:
        candidates = grid.within(centroids, band)
        near[candidates] |= (np.abs(grid.distance(centroids[candidates])) <= band) & grid.covers(centroids[candidates])
    labels, sizes = face_pieces(mesh.faces, len(mesh.vertices))
    share = np.bincount(labels, areas * near, minlength=len(sizes)) / np.maximum(np.bincount(labels, areas, minlength=len(sizes)), 1e-12)
    drop_piece = share >= ABSORBED_SHARE
    return drop_piece[labels], int(drop_piece.sum())


def finish_mesh(mesh: Mesh, views: Sequence[DepthView], camera_centres: np.ndarray, voxel_size: float, mode: str,
                options: Optional[FinishOptions] = None, camera_poses: Optional[np.ndarray] = None) -> FinishResult:
    """The finished mesh (see the module doc) of `mesh` (world metres, wound toward free space), judged
    by `views` (depth maps with their cameras) and the capture's `camera_centres` (C, 3).
    mode: FINISH_OFF (returned as it is), FINISH_CLEAN or FINISH_ROOM. camera_poses: (C, 4, 4)
    camera-to-world whose horizon says where up is (`planes.room_up`; None: the views' poses). The
    result's mesh has normals and the ADDED attribute, no colours."""
    if mode not in FINISH_MODES:
        raise ValueError(f"finish mode must be one of {FINISH_MODES}, got {mode!r}")
    options = options or FinishOptions()
    if mode == FINISH_OFF or len(mesh.faces) == 0:
        return FinishResult(mesh, [], {"mode": mode})
    tolerance = options.tolerance if options.tolerance is not None else max(2 * voxel_size, 0.06)
    cell = options.cell or voxel_size
    vertices = np.asarray(mesh.vertices, np.float64)
    faces = np.asarray(mesh.faces, np.int64)
    if camera_poses is None and views:
        camera_poses = np.stack([np.asarray(view.pose, np.float64) for view in views])
    # A metric capture's world is its own frame, which need not be level (the SUN3D room's is 19 deg off).
    centroids, areas, face_normals = face_geometry(vertices, faces)
    up, up_info = room_up(camera_poses, centroids, areas, face_normals)
    planes, layout = find_structural_planes(vertices, faces, camera_centres, options.min_plane_area, up=up)
    floor = next((p for p in planes if p.kind == FLOOR), None)
    if floor is not None and up_info["up_source"] == "camera horizon":
        # The horizon is a degree or two off (the cameras' roll), and a degree is 4 cm across a 5 m floor.
        # The floor's mean normal is finer where its normals are good (PatchMatch on SUN3D: 38 % of the
        # floor within 10 deg of the mean, the mean 0.7 deg from the truth's floor, the horizon 1.4), not
        # where they are crumpled (the fast sweep's: 19 %, 2.2 deg off: its sweep planes lean its normals).
        finer, agreement = floor_up(centroids, areas, face_normals, floor)
        turn = float(np.degrees(np.arccos(np.clip(finer @ up, -1.0, 1.0))))
        up_info["floor_normal_agreement"] = round(agreement, 3)
        if turn <= FLOOR_UP_MAX_TURN_DEG and agreement >= FLOOR_UP_MIN_AGREEMENT:
            again, again_layout = find_structural_planes(vertices, faces, camera_centres, options.min_plane_area, up=finer)
            if any(p.kind == FLOOR for p in again):
                planes, layout, up = again, again_layout, finer
                up_info = {**up_info, "up_source": "camera horizon, then the floor", "floor_turn_deg": round(turn, 2),
                           "up": [round(float(x), 4) for x in up]}
    stats: dict[str, Any] = {"mode": mode, "planes": [p.to_dict() for p in planes], **layout, **up_info,
                             "faces_in": int(len(faces))}
    floor = next((p for p in planes if p.kind == FLOOR), None)
    if floor is not None:  # what a glossy floor mirrors is no view through it
        views, reflections = without_reflections(views, floor.distance,
                                                  floor_extent(floor, centroids, face_normals, tolerance))
        stats["reflections"] = reflections.to_dict()

    grids = []
    drop = np.zeros(len(faces), bool)
    supported_behind = np.zeros(len(faces), bool)
    floor_grid = None
    for plane in sorted(planes, key=lambda p: p.kind != FLOOR):  # the floor first: the ceiling's fill needs it
        grid = plane_grid(plane, planes, centroids, areas, face_normals, plane.distance(centroids), tolerance, cell,
                          views, fill=mode == FINISH_ROOM)
        if grid is None:
            continue
        if plane.kind == FLOOR:
            floor_grid = grid
        elif plane.kind == CEILING and floor_grid is not None:
            # A room's ceiling is over its floor: none is added where there is no floor below.
            grid.keep &= grid.observed | over_floor(grid, floor_grid)
        grids.append(grid)
        vertex_distance = grid.distance(vertices)[faces]  # (F, 3)
        covered = grid.covers(centroids)
        # Hidden by the plane where it stands: no photo from the room sees there except through an opening.
        behind = (vertex_distance < -tolerance).all(axis=1) & grid.blocks(centroids)
        seen_there = behind & _seen_from_behind(vertices, faces, behind, plane, views, options.refuting_views)
        through_opening = np.zeros_like(behind)
        if plane.kind == WALL:
            through_opening = behind & ~seen_there & _seen_through_openings(vertices, faces, behind & ~seen_there, grid,
                                                                            views, options.refuting_views)
        supported_behind |= seen_there | through_opening
        drop |= behind & ~seen_there & ~through_opening
        grid.refute(centroids[seen_there])
        if mode == FINISH_ROOM:  # the plane's grid replaces the surface on it
            drop |= (np.abs(vertex_distance) <= tolerance).all(axis=1) & covered & ~grid.in_relief(centroids)
    if mode == FINISH_ROOM and options.furniture:
        # Furniture planes inside the room (furniture.py), found in what the structural planes left:
        # each patch's grid replaces the surface within its window not turned away from it.
        found = find_furniture_planes(centroids, areas, face_normals, up, layout["heading_deg"], planes, candidate=~drop)
        furniture_stats = []
        for patch in found:
            grid = furniture_grid(patch, centroids, cell, views, fill=True)
            if not grid.keep.any():  # cut by its relief into stretches smaller than furniture
                continue
            # A face whose vertices all lie within the window has its centroid there too.
            candidates = grid.within(centroids, FURNITURE_WINDOW)
            candidates = candidates[face_normals[candidates] @ patch.plane.normal > FLATTEN_COS]
            vertex_distance = grid.distance(vertices[faces[candidates]].reshape(-1, 3)).reshape(-1, 3)
            on = ((np.abs(vertex_distance) <= FURNITURE_WINDOW).all(axis=1) & grid.covers(centroids[candidates])
                  & ~grid.in_relief(centroids[candidates]))
            drop[candidates[on]] = True
            grids.append(grid)
            furniture_stats.append({**patch.plane.to_dict(), "spread_m": round(patch.spread, 4),
                                    "observed": int(grid.observed.sum()), "added": int(grid.added.sum()),
                                    "replaced_faces": int(on.sum())})
        stats["furniture"] = furniture_stats
    stats["dropped_behind_or_on_planes"] = int(drop.sum())
    stats["kept_behind_planes_seen"] = int((supported_behind & ~drop).sum())
    kept = keep_faces(Mesh(vertices.astype(np.float32), faces.astype(np.int32)), ~drop)

    votes = view_votes(kept.vertices, views)
    # Surface in free space goes face by face: most views that frame it saw past it (crumpled stereo
    # in front of a wall that the other views saw where it is).
    carved = votes.free()[np.asarray(kept.faces)].sum(axis=1) >= 2
    stats["carved_faces"] = int(carved.sum())
    kept = keep_faces(kept, ~carved)
    votes = view_votes(kept.vertices, views)
    # A surface point is seen by a share of the maps, so the views asked of a piece grow with their number
    # (the demo room's 36 maps: 2 and 6; the SUN3D room's 12: 1 and 2).
    min_views = options.min_views if options.min_views is not None else max(1, round(len(views) / VIEWS_PER_MIN_VIEW))
    if options.min_views is None:
        # No more than the mesh's typical surface gets: where the maps disagree (poses a degree or two off:
        # the realistic room_05001, 40 maps, half its surface seen by 1 view) asking 2 dropped a third of
        # the surface, as much of it near the truth as of what stayed (docs/experiments.md, issue 35).
        min_views = min(min_views, typical_support(votes.seen, np.asarray(kept.faces)))
    small_views = (options.small_piece_views if options.small_piece_views is not None
                   else max(2, round(len(views) / VIEWS_PER_SMALL_PIECE_VIEW)))
    # Small pieces are judged harder only where the room's structure was found: its planes then show the
    # room, and what is left in small pieces is stereo's debris around them; without it (a room whose floor
    # and walls stereo did not find) the small pieces are most of what the photos give.
    kinds = [p.kind for p in planes]
    structured = FLOOR in kinds and kinds.count(WALL) >= 2
    stats.update({"min_views": min_views, "small_piece_views": small_views if structured else None})
    if views:  # without any view there is no evidence to judge a piece by: all stay
        drop_piece, pieces, dropped = _pieces_to_drop(kept, votes, min_views, small_views if structured else 0)
        stats.update({"pieces_before": pieces, "pieces_dropped": dropped})
        kept = keep_faces(kept, ~drop_piece)
    if mode == FINISH_ROOM:
        absorbed = _pieces_absorbed(kept, grids, ABSORB_TOLERANCE_FACTOR * tolerance)
        stats["pieces_absorbed"] = int(absorbed[1])
        kept = keep_faces(kept, ~absorbed[0])
    out_vertices = np.asarray(kept.vertices, np.float64)

    if mode == FINISH_CLEAN:  # flatten what lies on a plane where the plane stands
        moved = np.zeros(len(out_vertices), bool)
        normals = vertex_normals(out_vertices, np.asarray(kept.faces, np.int64))
        for grid in grids:
            d = grid.distance(out_vertices)
            # Facing the plane's way (within 60 deg: crumpled wall surface does): a cabinet's side
            # standing on the floor is not pulled down onto it.
            facing = normals @ grid.plane.normal > FLATTEN_COS
            on = ((np.abs(d) <= tolerance) & facing & grid.covers(out_vertices) & ~grid.in_relief(out_vertices)
                  & ~moved)
            out_vertices[on] -= d[on, None] * grid.plane.normal
            moved |= on
        stats["flattened_vertices"] = int(moved.sum())

    parts_v, parts_f, parts_added = [out_vertices], [np.asarray(kept.faces, np.int64)], [np.zeros(len(out_vertices))]
    offset = len(out_vertices)
    added_area = 0.0
    if mode == FINISH_ROOM:
        for grid in grids:
            for cells, flag in ((grid.observed & grid.keep, 0.0), (grid.added, 1.0)):
                v, f = grid_mesh(grid, cells)
                parts_v.append(v)
                parts_f.append(f + offset)
                parts_added.append(np.full(len(v), flag))
                offset += len(v)
            added_area += float(grid.added.sum()) * grid.cell ** 2
    stats["added_area_m2"] = round(added_area, 3)
    stats["plane_cells"] = [{"kind": g.plane.kind, "observed": int(g.observed.sum()), "added": int(g.added.sum()),
                             "free": int(g.free.sum()), "relief": int(g.relief.sum()), "flat_band_m": round(g.band, 4),
                             "shift_m": [round(float(g.shift.min()), 3), round(float(g.shift.max()), 3)]} for g in grids]
    out_vertices, out_faces = np.concatenate(parts_v), np.concatenate(parts_f)
    added = np.concatenate(parts_added)
    if len(out_faces):
        used = np.zeros(len(out_vertices), bool)
        used[out_faces.ravel()] = True
        added = added[used]
        out_vertices, out_faces = compact(out_vertices, out_faces)
    else:
        out_vertices, added = np.zeros((0, 3)), np.zeros(0)
    out = Mesh(out_vertices.astype(np.float32), out_faces.astype(np.int32),
               vertex_normals(out_vertices, out_faces) if len(out_faces) else np.zeros((0, 3), np.float32),
               attributes={ADDED: added.astype(np.float32)})
    stats["faces_out"] = int(len(out_faces))
    return FinishResult(out, planes, stats)
