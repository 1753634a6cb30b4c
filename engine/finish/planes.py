"""The room's structural planes (floor, ceiling, walls) found in a reconstructed surface.

Gravity is known, so the search is split as indoor layout methods split it. Up is world Z, unless the
cameras' horizon says the world is tilted and the surface agrees (a metric capture's own frame is kept
as it is, and the SUN3D room's is 19 deg off level): then the planes are found in a frame levelled by
the horizon (`room_up`), and the finishing levels it again by the floor's own normal where that is
good (`floor_up`, engine/finish/finishing.py).
- floor and ceiling: area-weighted histograms of the height of the faces that face up (floor) or
  down (ceiling); the floor is the lowest strong peak below the cameras with little surface below it
  (stereo's error may put crumpled surface there, but not a lower up-facing one) that is not the echo
  of a room-sized one above it (a glossy floor's reflection), the ceiling the highest above them (a
  table top is a smaller, higher peak).
- walls: faces that face sideways vote with their normal's heading; the room's Manhattan frame is the
  heading (mod 90 deg) that most wall area agrees with. Where it holds (most vertical area within
  `MANHATTAN_TOLERANCE_DEG` of its four directions) those four directions are the walls' normals,
  otherwise the strong peaks of the heading histogram are. Along each direction an area histogram of
  position gives the candidate planes.
- a candidate is a *wall* only if it bounds the room: little surface lies behind it across its span
  (a cabinet front has the wall above it behind it) and the cameras are in front of it.

Normals point into the room (toward free space and the cameras): a face's winding follows the
reconstruction's normals (`engine.mesh_io.Mesh`). Everything is numpy: a million faces take about a
second.
"""

from __future__ import annotations

from dataclasses import dataclass, field
from typing import Optional

import numpy as np
from scipy.spatial import cKDTree

FLOOR, CEILING, WALL = "floor", "ceiling", "wall"

HORIZONTAL_COS = 0.9  # |n_z| above this: a face faces up or down (within 26 deg)
VERTICAL_SIN = 0.35  # |n_z| below this: a face faces sideways (within 20 deg of vertical)
HEADING_TOLERANCE_DEG = 20.0  # a wall face's heading within this of its wall's normal
MANHATTAN_TOLERANCE_DEG = 15.0
MANHATTAN_SHARE = 0.5  # of the vertical area within tolerance of the Manhattan directions: the frame holds
MANHATTAN_SHARPNESS = 1.5  # the walls' position histograms this much sharper square to the frame: it holds
MANHATTAN_FACING_DEG = 45.0  # in a Manhattan frame a wall's faces face within this of its normal (crumpled stereo)
HISTOGRAM_BIN = 0.02  # m
PEAK_WINDOW = 0.06  # m either side of a peak: the area that supports it
MIN_PLANE_AREA = 0.3  # m^2 of surface a structural plane needs
MIN_WALL_HEIGHT = 1.2  # m: a wall's surface spans at least this height (a counter's or a shelf's front does not)
BACK_SIDE_SHARE = 0.5  # of a candidate wall's area whose nearest camera stands behind it: it faces them
OPENING_CLEARANCE = 0.3  # m from a wall's own surface to where the walk crossed its plane: through a door
BEHIND_MARGIN = 0.2  # m behind a candidate wall before surface counts as "behind" it
# Surface behind a wall across its span, as a share of the wall's own area: a cabinet front has more
# wall behind it than its own area; a wall has at most what its windows and doors show of outside.
MAX_BEHIND_SHARE = 1.0
OPENING_CELL = 0.1  # m: the grid a candidate wall's own surface is rasterised on to find its openings
MAX_OPENING_WIDTH = 2.0  # m: a gap in a wall's surface this wide, with wall on both sides, can be a door
OPENING_CAMERAS = 24  # cameras (evenly spaced) whose sight lines test where surface behind a wall was seen through
# Area sums over a big space's faces are estimated from every k-th face once there are more than this
# many (the same sums to within a percent; a 20 x 33 m corridor has a million faces).
AREA_SAMPLE_FACES = 50_000
MAX_BELOW_FLOOR_SHARE = 3.0  # surface below a floor, as a share of its area (stereo's error puts some there)
# ... counted down to this far below the floor: what a table top has below it (the floor, the walls'
# lower parts) is within its own height, while depth noise of poses a degree or two off spreads thinly
# as far as the room's bounds reach (room_07002 on poses with 61 frames unrefined, bounds from the
# frusta: 11 m^2 spread over 1.5 m below a 3.2 m^2 floor, which was then not found: 3,472 pieces).
BELOW_FLOOR_DEPTH = 0.7  # m
# Up-facing peaks closer than this are one floor: poses left a degree or two off spread a floor over
# 15-20 cm in two or three humps (room_07002: 1.5 and 2.3 m^2, 14 cm apart), each too small on its own
# for the surface below it. Table tops stand 40 cm and more above the floor.
FLOOR_LAYER = 0.2  # m
MAX_UP_BELOW_FLOOR_SHARE = 0.5  # up-facing surface below a floor (a lower floor: the candidate is a table top)
# A floor candidate under a room-sized one (over FURNITURE_MAX_AREA m^2) with ECHO_AREA_RATIO times its
# area, both with little below them, is that floor's echo, not the floor: the 3D Scanner App corridor's
# glossy floor gave stereo 2.5 m^2 of mirrored lights 26 cm below its 64 m^2 floor in one run and
# 8.2 m^2 14 cm below its 58 m^2 in another, each then taken as the floor and the whole floor laid low.
ECHO_AREA_RATIO = 2.0
FURNITURE_MAX_AREA = 6.0  # m^2: a large dining table is 2-3 m^2
# The room's up from the cameras' horizon (`room_up`): considered from MIN_TILT_DEG off world Z; beyond
# MAX_TILT_DEG the cameras were not held level, or the world is not Z up at all.
MIN_TILT_DEG = 1.0
MAX_TILT_DEG = 30.0
FLOOR_NORMAL_AGREE_DEG = 10.0  # a floor face's normal "agrees" with the floor's mean normal within this
# The horizon is taken only where the surface lies this much more level along it than along world Z (SUN3D:
# 3.7 x with PatchMatch, 2.2 x with the fast sweep; a level synthetic room whose noisy poses tilt the horizon
# 3 deg: 1.0 x, a tie its crumpled surface cannot break).
LEVEL_SHARPER = 1.5
HORIZON_MIN_SPREAD = 0.03  # mean sin^2 of the x axes' spread about their mean: under ~10 deg of headings


@dataclass
class StructuralPlane:
    """A plane n . x = offset with unit `normal` (3,) pointing into the room; `kind` floor / ceiling /
    wall; `area` the m^2 of surface that supports it; `axes` (2, 3) unit in-plane axes (u, v) with
    u x v = normal (walls: u horizontal, v = +Z)."""

    kind: str
    normal: np.ndarray
    offset: float
    area: float
    axes: np.ndarray = field(default_factory=lambda: np.zeros((2, 3)))

    def distance(self, points: np.ndarray) -> np.ndarray:
        """(N,) signed distance of points (N, 3): positive in the room, negative behind the plane."""
        return np.asarray(points, np.float64) @ self.normal - self.offset

    def to_plane(self, points: np.ndarray) -> np.ndarray:
        """(N, 2) in-plane coordinates (along u, v) of points (N, 3) projected onto the plane."""
        return np.asarray(points, np.float64) @ self.axes.T

    def from_plane(self, coords: np.ndarray) -> np.ndarray:
        """(N, 3) world points on the plane at in-plane coordinates (N, 2)."""
        return self.normal * self.offset + np.asarray(coords, np.float64) @ self.axes

    def to_dict(self) -> dict:
        return {"kind": self.kind, "normal": [round(float(x), 4) for x in self.normal],
                "offset": round(float(self.offset), 4), "area_m2": round(float(self.area), 3)}


def face_geometry(vertices: np.ndarray, faces: np.ndarray) -> tuple[np.ndarray, np.ndarray, np.ndarray]:
    """(centroids (F, 3), areas (F,), unit normals (F, 3) following the winding), float64."""
    v = np.asarray(vertices, np.float64)
    a, b, c = v[faces[:, 0]], v[faces[:, 1]], v[faces[:, 2]]
    cross = np.cross(b - a, c - a)
    length = np.linalg.norm(cross, axis=1)
    normals = cross / np.maximum(length, 1e-12)[:, None]
    return (a + b + c) / 3.0, 0.5 * length, normals


def _histogram_peaks(values: np.ndarray, weights: np.ndarray, min_weight: float,
                     window_m: float = PEAK_WINDOW) -> list[tuple[float, float]]:
    """Peaks of the weighted histogram of `values` (N,): [(position, weight within `window_m`)], strongest
    first, each at least `min_weight` and 2 windows from any stronger one."""
    if len(values) == 0:
        return []
    lo = float(values.min()) - 2 * window_m
    bins = int(np.ceil((float(values.max()) + 2 * window_m - lo) / HISTOGRAM_BIN)) + 1
    hist = np.bincount(((values - lo) / HISTOGRAM_BIN).astype(np.int64), weights, minlength=bins)
    half = int(round(window_m / HISTOGRAM_BIN))
    window = np.convolve(hist, np.ones(2 * half + 1), mode="same")  # area within +-PEAK_WINDOW of each bin
    sharp = np.convolve(hist, [1.0, 2.0, 1.0], mode="same")  # where a peak is; `window`: how strong
    peaks: list[tuple[float, float]] = []
    for index in np.argsort(-sharp):
        weight = float(window[index])
        if sharp[index] <= 0:
            break
        if weight < min_weight:
            continue
        position = lo + (index + 0.5) * HISTOGRAM_BIN
        if all(abs(position - p) > 2 * window_m for p, _ in peaks):
            peaks.append((position, weight))
    return peaks


def _echo_of_a_floor(lower: tuple[float, float], upper: tuple[float, float]) -> bool:
    """Whether the floor candidate `lower` (height, area) is an echo of the higher candidate `upper`,
    both with little surface below them: `upper` is larger than furniture and has ECHO_AREA_RATIO
    times `lower`'s area. A glossy floor's stereo matches the mirrored lights and walls below it; a
    lower floor under a table top is no echo (the table top would have that floor below it and fail
    as a floor, and is no room-sized surface)."""
    return upper[0] > lower[0] and upper[1] >= max(FURNITURE_MAX_AREA, ECHO_AREA_RATIO * lower[1])


def _floor_layers(heights: np.ndarray, areas: np.ndarray, min_area: float) -> list[tuple[float, float]]:
    """Floor candidates from the heights (N,) and areas (N,) of up-facing faces: the histogram's peaks,
    those within FLOOR_LAYER of each other joined into one layer: [(area-weighted median height of
    the layer, its area within PEAK_WINDOW of its peaks)], lowest first. A layer spans at most
    FLOOR_LAYER from its lowest peak (no chains of table tops)."""
    peaks = sorted(_histogram_peaks(heights, areas, min_area))
    layers: list[list[tuple[float, float]]] = []
    for peak in peaks:
        if layers and peak[0] - layers[-1][0][0] <= FLOOR_LAYER:
            layers[-1].append(peak)
        else:
            layers.append([peak])
    joined = []
    for layer in layers:
        if len(layer) == 1:
            joined.append(layer[0])
            continue
        inside = (heights >= layer[0][0] - PEAK_WINDOW) & (heights <= layer[-1][0] + PEAK_WINDOW)
        joined.append((_weighted_median(heights[inside], areas[inside]), float(areas[inside].sum())))
    return joined


def _weighted_median(values: np.ndarray, weights: np.ndarray) -> float:
    """The weighted median of `values` (N,) with `weights` (N,), N > 0."""
    order = np.argsort(values)
    cumulative = np.cumsum(weights[order])
    return float(values[order][np.searchsorted(cumulative, 0.5 * cumulative[-1])])


def _refine_offset(values: np.ndarray, weights: np.ndarray, around: float, window_m: float = PEAK_WINDOW) -> float:
    """The area-weighted median of `values` within `window_m` of `around`: the plane's offset."""
    near = np.abs(values - around) <= window_m
    if not near.any():
        return around
    return _weighted_median(values[near], weights[near])


def manhattan_heading(normals: np.ndarray, areas: np.ndarray) -> tuple[float, float]:
    """(heading in radians in [0, pi/2), share of the area within MANHATTAN_TOLERANCE_DEG of the four
    directions) of horizontal unit normals (N, 3) weighted by `areas` (N,)."""
    if len(normals) == 0 or areas.sum() <= 0:
        return 0.0, 0.0
    theta = np.arctan2(normals[:, 1], normals[:, 0])
    folded = np.degrees(np.mod(theta, np.pi / 2))  # 0..90
    hist = np.bincount(np.minimum(folded.astype(np.int64), 89), areas, minlength=90)
    spread = int(MANHATTAN_TOLERANCE_DEG // 2)
    kernel = np.ones(2 * spread + 1)
    circular = np.convolve(np.concatenate([hist[-spread:], hist, hist[:spread]]), kernel, mode="valid")
    heading = np.radians((int(np.argmax(circular)) + 0.5) % 90)
    for _ in range(3):  # the circular mean of 4 x heading near the peak: symmetric noise cancels
        offset = np.mod(theta - heading + np.pi / 4, np.pi / 2) - np.pi / 4  # from the nearest direction
        near = np.abs(offset) <= np.radians(MANHATTAN_TOLERANCE_DEG)
        if not near.any():
            break
        heading = heading + np.angle(np.sum(areas[near] * np.exp(4j * offset[near]))) / 4
    return float(np.mod(heading, np.pi / 2)), float(areas[near].sum() / areas.sum())


def _wall_directions(normals: np.ndarray, areas: np.ndarray) -> tuple[list[np.ndarray], float, bool]:
    """Candidate wall normals (unit, horizontal), the Manhattan heading and whether the frame holds."""
    heading, share = manhattan_heading(normals, areas)
    if share >= MANHATTAN_SHARE:
        return [np.array([np.cos(heading + k * np.pi / 2), np.sin(heading + k * np.pi / 2), 0.0]) for k in range(4)], heading, True
    theta = np.degrees(np.mod(np.arctan2(normals[:, 1], normals[:, 0]), 2 * np.pi))
    hist = np.bincount(np.minimum(theta.astype(np.int64), 359), areas, minlength=360)
    window = np.convolve(np.concatenate([hist[-10:], hist, hist[:10]]), np.ones(21), mode="valid")
    directions: list[float] = []
    for index in np.argsort(-window):
        if window[index] < 0.1 * areas.sum():
            break
        if all(min(abs(index - d), 360 - abs(index - d)) > 30 for d in directions):
            directions.append(float(index))
    return [np.array([np.cos(np.radians(d + 0.5)), np.sin(np.radians(d + 0.5)), 0.0]) for d in directions], heading, False


def _directions(heading: float) -> list[np.ndarray]:
    """The four horizontal unit directions of a Manhattan frame at `heading` (radians)."""
    return [np.array([np.cos(heading + k * np.pi / 2), np.sin(heading + k * np.pi / 2), 0.0]) for k in range(4)]


def position_heading(centroids: np.ndarray, areas: np.ndarray, normals: np.ndarray) -> tuple[float, float]:
    """(heading in radians in [0, pi/2), sharpness ratio) of the room's Manhattan frame from where its
    sideways-facing surface lies: for each candidate heading the area histograms of position along the
    two axes (faces facing within 60 deg of each axis) are squared and summed; walls make the sum peak
    where the axes are square to them. The ratio is the best sum over the median one (1 for no frame)."""
    sideways = np.flatnonzero(np.abs(normals[:, 2]) < 0.5)
    sideways = sideways[::max(1, -(-len(sideways) // AREA_SAMPLE_FACES))]  # every k-th face (AREA_SAMPLE_FACES)
    c, a, n = centroids[sideways, :2], areas[sideways], normals[sideways, :2]
    if len(c) < 10:
        return 0.0, 1.0

    def score(angle: float) -> float:
        total = 0.0
        for axis in (np.array([np.cos(angle), np.sin(angle)]), np.array([-np.sin(angle), np.cos(angle)])):
            facing = np.abs(n @ axis) > 0.5
            if not facing.any():
                continue
            position = c[facing] @ axis
            bins = np.floor((position - position.min()) / HISTOGRAM_BIN).astype(np.int64)
            total += float(np.sum(np.bincount(bins, a[facing]) ** 2))
        return total

    coarse = np.radians(np.arange(0.0, 90.0, 1.0))
    scores = np.array([score(t) for t in coarse])
    best = float(coarse[int(np.argmax(scores))])
    fine = best + np.radians(np.arange(-1.0, 1.01, 0.1))
    fine_scores = np.array([score(t) for t in fine])
    heading = float(np.mod(fine[int(np.argmax(fine_scores))], np.pi / 2))
    return heading, float(fine_scores.max() / max(np.median(scores), 1e-12))


def _heading_from_positions(centroids: np.ndarray, areas: np.ndarray, normals: np.ndarray, vertical: np.ndarray,
                            directions: list[np.ndarray], heading: float) -> float:
    """The Manhattan heading refined from where the wall surfaces lie: per direction, the faces of its
    strongest position peak give a line (the principal axis of their xy positions); the lines' headings
    (mod 90 deg) are averaged by area."""
    votes = []
    cos_tolerance = np.cos(np.radians(MANHATTAN_FACING_DEG))
    for direction in directions:
        facing = vertical & (normals @ direction > cos_tolerance)
        position = centroids[facing] @ direction
        peaks = _histogram_peaks(position, areas[facing], MIN_PLANE_AREA)
        if not peaks:
            continue
        near = np.abs(position - peaks[0][0]) <= PEAK_WINDOW
        xy, weight = centroids[facing][near, :2], areas[facing][near]
        if weight.sum() <= 0 or len(xy) < 10:
            continue
        centred = xy - np.average(xy, axis=0, weights=weight)
        _, vectors = np.linalg.eigh((centred * weight[:, None]).T @ centred)
        tangent = vectors[:, 1]  # the largest spread: along the wall
        votes.append((np.arctan2(tangent[1], tangent[0]), weight.sum()))
    if not votes:
        return heading
    angles, weights = np.array([a for a, _ in votes]), np.array([w for _, w in votes])
    offset = np.mod(angles - heading + np.pi / 4, np.pi / 2) - np.pi / 4
    return float(np.mod(heading + np.angle(np.sum(weights * np.exp(4j * offset))) / 4, np.pi / 2))


def camera_horizon_up(poses: np.ndarray) -> Optional[np.ndarray]:
    """The room's up (3,) unit from hand-held cameras (C, 4, 4) camera-to-world: the normal of the
    plane their x axes (OpenCV right) lie in, signed like their mean up (-y). None when it is not
    measured: fewer than 3 cameras, or their headings too alike to span a plane.

    People hold a camera with little roll but tilt it up and down freely, so the x axis is close to
    horizontal while the mean of the up vectors leans back by the mean pitch (the SUN3D study room's
    frame is its cameras' mean up and is 19 deg off the truth's floor; its cameras' x axes give the
    floor's normal within 2 deg: docs/experiments.md, "A finished room for VR", issue 35)."""
    poses = np.asarray(poses, np.float64).reshape(-1, 4, 4)
    if len(poses) < 3:
        return None
    right = poses[:, :3, 0]
    values, vectors = np.linalg.eigh(right.T @ right)
    if values[1] < HORIZON_MIN_SPREAD * len(poses):
        return None  # all look the same way: the x axes do not span a plane
    up = vectors[:, 0]
    camera_up = -poses[:, :3, 1].sum(axis=0)
    return up if up @ camera_up >= 0 else -up


def rotation_to_z(up: np.ndarray) -> np.ndarray:
    """(3, 3) the smallest rotation taking unit `up` (3,) to +Z."""
    up = np.asarray(up, np.float64) / np.linalg.norm(up)
    axis = np.cross(up, [0.0, 0.0, 1.0])
    sin, cos = float(np.linalg.norm(axis)), float(up[2])
    if sin < 1e-12:
        return np.eye(3) if cos > 0 else np.diag([1.0, -1.0, -1.0])
    k = axis / sin
    skew = np.array([[0.0, -k[2], k[1]], [k[2], 0.0, -k[0]], [-k[1], k[0], 0.0]])
    return np.eye(3) + sin * skew + (1.0 - cos) * skew @ skew


def level_sharpness(centroids: np.ndarray, areas: np.ndarray, normals: np.ndarray, up: np.ndarray) -> float:
    """How level the surface lies if `up` (3,) unit is up: of the faces facing up or down along it
    (centroids, normals (F, 3), areas (F,)), the sum of squares of their area histogram of height over the
    square of their area (1 when all lie at one height; a tilted floor spreads over many bins)."""
    flat = np.abs(normals @ up) > HORIZONTAL_COS
    if not flat.any():
        return 0.0
    height = centroids[flat] @ up
    bins = np.floor((height - height.min()) / HISTOGRAM_BIN).astype(np.int64)
    histogram = np.bincount(bins, areas[flat])
    return float(np.sum(histogram ** 2) / max(float(areas[flat].sum()) ** 2, 1e-12))


def room_up(camera_poses: Optional[np.ndarray], centroids: np.ndarray, areas: np.ndarray,
            normals: np.ndarray) -> tuple[np.ndarray, dict]:
    """(up (3,) unit, info) the direction the planes are found along: world Z, or the cameras' horizon
    (`camera_horizon_up`) when it is 1 to MAX_TILT_DEG from Z and the surface (faces: centroids, normals
    (F, 3), areas (F,)) lies clearly more level along it (`level_sharpness`, LEVEL_SHARPER times Z's). An SfM world is levelled by its
    floor, which knows up better than the horizon of cameras held with a few degrees of roll (the demo
    room's horizon is 3.8 deg off); a metric capture's own frame may be far off (SUN3D's: 19 deg)."""
    z = np.array([0.0, 0.0, 1.0])
    up = camera_horizon_up(camera_poses) if camera_poses is not None and len(camera_poses) else None
    if up is None:
        return z, {"up_source": "world Z (no camera horizon)", "tilt_deg": 0.0}
    tilt = float(np.degrees(np.arccos(np.clip(up[2], -1.0, 1.0))))
    info = {"horizon_tilt_deg": round(tilt, 2)}
    if tilt < MIN_TILT_DEG or tilt > MAX_TILT_DEG:
        return z, {"up_source": "world Z", **info, "tilt_deg": 0.0}
    sharp_z, sharp_up = (level_sharpness(centroids, areas, normals, d) for d in (z, up))
    info.update({"level_sharpness_z": round(sharp_z, 4), "level_sharpness_horizon": round(sharp_up, 4)})
    if sharp_up < LEVEL_SHARPER * sharp_z:
        return z, {"up_source": "world Z", **info, "tilt_deg": 0.0}
    return up, {"up_source": "camera horizon", **info, "tilt_deg": round(tilt, 2), "up": [round(float(x), 4) for x in up]}


def floor_up(centroids: np.ndarray, areas: np.ndarray, normals: np.ndarray, floor: StructuralPlane) -> tuple[np.ndarray, float]:
    """(up (3,) unit, agreement) of the floor: the area-weighted mean normal of the up-facing faces
    (centroids, normals (F, 3), areas (F,)) within PEAK_WINDOW of `floor`, and the share of their area
    within FLOOR_NORMAL_AGREE_DEG of that mean (how far their normals can be trusted)."""
    on = (normals @ floor.normal > HORIZONTAL_COS) & (np.abs(floor.distance(centroids)) <= PEAK_WINDOW)
    mean = (normals[on] * areas[on, None]).sum(axis=0)
    length = float(np.linalg.norm(mean))
    if length <= 0:
        return floor.normal.copy(), 0.0
    mean = mean / length
    agree = normals[on] @ mean > np.cos(np.radians(FLOOR_NORMAL_AGREE_DEG))
    return mean, float(areas[on][agree].sum() / areas[on].sum())


def seen_through_openings(wall_uz: np.ndarray, behind: np.ndarray, cameras: np.ndarray, direction: np.ndarray,
                          offset: float, u_axis: np.ndarray) -> np.ndarray:
    """(B,) bool: which of the points `behind` (B, 3) a camera could have seen through an opening of a
    candidate wall: the sight line from one of `cameras` (C, 3) in front of the wall (direction . x >
    offset) crosses the wall's plane where the wall has no surface of its own but has some above, as
    in a window or a door under its lintel. wall_uz (N, 2): the wall's own surface as (along u_axis,
    height) points. Surface seen above a cabinet front (nothing of the candidate above the crossing)
    stays evidence that the candidate is not a wall."""
    through = np.zeros(len(behind), bool)
    if len(behind) == 0 or len(wall_uz) == 0 or len(cameras) == 0:
        return through
    origin = wall_uz.min(axis=0)
    cells = np.floor((wall_uz - origin) / OPENING_CELL).astype(np.int64)
    shape = cells.max(axis=0) + 1
    occupied = np.zeros(shape, bool)
    occupied[cells[:, 0], cells[:, 1]] = True
    # Per column, the highest row with wall surface: an opening lies below it.
    rows = np.arange(shape[1])
    top = np.where(occupied.any(axis=1), np.max(np.where(occupied, rows[None, :], -1), axis=1), -1)
    # Or wall surface on both sides in the same row, within a door's width: a door whose lintel stereo
    # did not find (plain walls above 2 m often are not). Above a cabinet front nothing of it is beside.
    columns = np.arange(shape[0])[:, None]
    left = np.maximum.accumulate(np.where(occupied, columns, -1), axis=0)  # nearest occupied column at or left of each
    right = np.minimum.accumulate(np.where(occupied, columns, shape[0])[::-1], axis=0)[::-1]
    flanked = (left >= 0) & (right < shape[0]) & (right - left <= int(np.ceil(MAX_OPENING_WIDTH / OPENING_CELL)))
    in_front = cameras[cameras @ direction > offset + 1e-3]
    if len(in_front) > OPENING_CAMERAS:
        in_front = in_front[np.round(np.linspace(0, len(in_front) - 1, OPENING_CAMERAS)).astype(np.int64)]
    behind_depth = behind @ direction
    for camera in in_front:
        camera_depth = float(camera @ direction)
        t = (camera_depth - offset) / np.maximum(camera_depth - behind_depth, 1e-9)  # behind: depth < offset
        crossing = camera + t[:, None] * (behind - camera)
        cell = np.floor((np.stack([crossing @ u_axis, crossing[:, 2]], axis=1) - origin) / OPENING_CELL).astype(np.int64)
        inside = (cell[:, 0] >= 0) & (cell[:, 0] < shape[0]) & (cell[:, 1] >= 0) & (cell[:, 1] < shape[1])
        col, row = np.where(inside, cell[:, 0], 0), np.where(inside, cell[:, 1], 0)
        through |= inside & ~occupied[col, row] & ((top[col] > row) | flanked[col, row])
    return through


def _seen_from_its_back(points: np.ndarray, areas: np.ndarray, cameras: np.ndarray, direction: np.ndarray,
                        offset: float) -> bool:
    """Whether most of a candidate wall's surface (`points` (N, 3) with `areas` (N,), up-aligned frame) has
    its nearest camera (of `cameras` (C, 3), horizontally) behind the wall (direction . x < offset): the
    photos that saw it best stood on its back side. It is then the wall of the room they stood in, seen
    through (glass, whose stereo surface may face either way), and is taken facing them. On the 3D
    Scanner App corridor the glass office fronts of the first leg gave a 3.5 m^2 "wall" facing into the
    offices whose back cut the whole leg's floor from the floor plane (78 % of its area had its nearest
    camera behind it; 0 % for every other wall)."""
    _, nearest = cKDTree(cameras[:, :2]).query(points[:, :2])
    behind = cameras[nearest] @ direction < offset
    return bool(areas[behind].sum() > BACK_SIDE_SHARE * areas.sum())


def _walked_through_an_opening(wall_uz: np.ndarray, cameras: np.ndarray, direction: np.ndarray, offset: float,
                               u_axis: np.ndarray) -> bool:
    """Whether the walk (`cameras` (C, 3) in capture order) crosses the plane direction . x = offset
    between two consecutive cameras where none of the wall's own surface (`wall_uz` (N, 2): along
    `u_axis`, height) lies within OPENING_CLEARANCE of the crossing: through a door in it. A glass front
    the walk went along is crossed at most where its line meets the walk's corner, by its own surface; a
    door frame across a corridor, where the walker passed through it."""
    side = cameras @ direction - offset
    front = side >= 0  # a camera on the plane counts as in front: the step off it crosses
    crossing = np.flatnonzero(front[:-1] != front[1:])
    if len(crossing) == 0 or len(wall_uz) == 0:
        return False
    t = side[crossing] / (side[crossing] - side[crossing + 1])
    points = cameras[crossing] + t[:, None] * (cameras[crossing + 1] - cameras[crossing])
    clearance, _ = cKDTree(wall_uz).query(np.stack([points @ u_axis, points[:, 2]], axis=1))
    return bool(np.any(clearance > OPENING_CLEARANCE))


def _wall(direction: np.ndarray, offset: float, area: float) -> StructuralPlane:
    """A wall facing `direction` (3,) horizontal unit, at `offset`, with u horizontal and v = +Z."""
    return StructuralPlane(WALL, direction.copy(), offset, area,
                           np.stack([np.cross([0.0, 0.0, 1.0], direction), np.array([0.0, 0.0, 1.0])]))


def _found_already(planes: list[StructuralPlane], direction: np.ndarray, offset: float) -> bool:
    """Whether `planes` has a wall facing `direction` within two peak windows of `offset`."""
    return any(p.kind == WALL and p.normal @ direction > 0.99 and abs(p.offset - offset) < 2 * PEAK_WINDOW for p in planes)


def find_structural_planes(vertices: np.ndarray, faces: np.ndarray, camera_centres: np.ndarray,
                           min_area: float = MIN_PLANE_AREA, up: Optional[np.ndarray] = None,
                           ) -> tuple[list[StructuralPlane], dict]:
    """Floor, ceiling and walls of a room mesh (vertices (V, 3) world metres, faces (F, 3) wound toward
    free space) seen from cameras at `camera_centres` (C, 3). up: the room's up (3,) unit in the world
    (None: world Z); the planes are found in a frame where it is +Z and returned in the world.

    Returns (planes, info): planes floor first, then ceiling, then walls; info the Manhattan heading
    (degrees, in the up-aligned frame) and whether it holds."""
    if up is not None and float(np.asarray(up, np.float64)[2]) < 1.0 - 1e-9:
        rotation = rotation_to_z(up)
        planes, info = find_structural_planes(np.asarray(vertices, np.float64) @ rotation.T, faces,
                                              np.asarray(camera_centres, np.float64).reshape(-1, 3) @ rotation.T,
                                              min_area)
        # n . (R x) = (R^T n) . x: the offset stays, normal and axes turn back.
        return [StructuralPlane(p.kind, p.normal @ rotation, p.offset, p.area, p.axes @ rotation) for p in planes], info
    centroids, areas, normals = face_geometry(vertices, faces)
    cameras = np.asarray(camera_centres, np.float64).reshape(-1, 3)
    low, high = (float(cameras[:, 2].min()), float(cameras[:, 2].max())) if len(cameras) else (np.inf, -np.inf)
    vertical = np.abs(normals[:, 2]) < VERTICAL_SIN
    horizontal_normals = normals[vertical, :2]
    horizontal_normals = horizontal_normals / np.maximum(np.linalg.norm(horizontal_normals, axis=1, keepdims=True), 1e-12)
    wall_normals = np.concatenate([horizontal_normals, np.zeros((len(horizontal_normals), 1))], axis=1)
    # Where the walls stand says the room's frame better than how crumpled stereo surface faces.
    heading, sharpness = position_heading(centroids, areas, normals)
    manhattan = sharpness >= MANHATTAN_SHARPNESS
    if manhattan:
        heading = _heading_from_positions(centroids, areas, normals, vertical, _directions(heading), heading)
        directions = _directions(heading)
    else:
        directions, heading, manhattan = _wall_directions(wall_normals, areas[vertical])
        if manhattan:
            heading = _heading_from_positions(centroids, areas, normals, vertical, directions, heading)
            directions = _directions(heading)
    u_floor = np.array([np.cos(heading), np.sin(heading), 0.0])
    planes: list[StructuralPlane] = []

    up = normals[:, 2] > HORIZONTAL_COS
    # The floor bounds the room from below: little surface lies below it. Stereo's depth error puts
    # some there (the fast sweep on SUN3D's carpet: 2.1 m^2 of crumpled surface below a 1.4 m^2 floor),
    # but not facing up as a lower floor would; a table top has the floor below it.
    floor_peaks = [p for p in _floor_layers(centroids[up, 2], areas[up], min_area)
                   if p[0] < low - 0.3
                   and areas[(centroids[:, 2] < p[0] - BEHIND_MARGIN)
                             & (centroids[:, 2] >= p[0] - BELOW_FLOOR_DEPTH)].sum() <= MAX_BELOW_FLOOR_SHARE * p[1]
                   and areas[up & (centroids[:, 2] < p[0] - BEHIND_MARGIN)].sum() <= MAX_UP_BELOW_FLOOR_SHARE * p[1]]
    floor_peaks = [p for p in floor_peaks if not any(_echo_of_a_floor(p, q) for q in floor_peaks)]
    if floor_peaks:
        z, weight = min(floor_peaks)
        offset = _refine_offset(centroids[up, 2], areas[up], z)
        planes.append(StructuralPlane(FLOOR, np.array([0.0, 0.0, 1.0]), offset, weight,
                                      np.stack([u_floor, np.cross([0.0, 0.0, 1.0], u_floor)])))
    down = normals[:, 2] < -HORIZONTAL_COS
    # The ceiling bounds the room from above: little surface lies above it (a shelf's underside has the
    # walls going on above it).
    ceiling_peaks = [p for p in _histogram_peaks(centroids[down, 2], areas[down], min_area)
                     if p[0] > high + 0.1 and areas[centroids[:, 2] > p[0] + BEHIND_MARGIN].sum() <= MAX_BEHIND_SHARE * p[1]]
    if ceiling_peaks:
        z, weight = max(ceiling_peaks)
        offset = _refine_offset(centroids[down, 2], areas[down], z)
        # n = -Z, so n . x = -z: the offset is -height; u x v must be -Z.
        planes.append(StructuralPlane(CEILING, np.array([0.0, 0.0, -1.0]), -offset, weight,
                                      np.stack([u_floor, np.cross([0.0, 0.0, -1.0], u_floor)])))

    z_lo = next((p.offset for p in planes if p.kind == FLOOR), float(centroids[:, 2].min()) if len(centroids) else 0.0)
    z_hi = next((-p.offset for p in planes if p.kind == CEILING), float(centroids[:, 2].max()) if len(centroids) else 0.0)
    cos_tolerance = np.cos(np.radians(MANHATTAN_FACING_DEG if manhattan else HEADING_TOLERANCE_DEG))
    seen_through = []  # walls seen from their back: (direction facing the cameras, offset, area)
    for direction in directions:
        facing = vertical & (normals @ direction > cos_tolerance)
        position = centroids[facing] @ direction
        u_axis = np.cross([0.0, 0.0, 1.0], direction)  # u x Z = direction
        for peak, weight in _histogram_peaks(position, areas[facing], min_area):
            offset = _refine_offset(position, areas[facing], peak)
            near = np.abs(position - offset) <= PEAK_WINDOW
            if near.sum() < 3:
                continue
            heights = centroids[facing][near, 2]
            if np.percentile(heights, 98) - np.percentile(heights, 2) < MIN_WALL_HEIGHT:
                continue
            along = centroids[facing][near] @ u_axis
            span = np.percentile(along, 1), np.percentile(along, 99)
            all_along = centroids @ u_axis
            behind = ((centroids @ direction < offset - BEHIND_MARGIN) & (all_along >= span[0]) & (all_along <= span[1])
                      & (centroids[:, 2] >= z_lo) & (centroids[:, 2] <= z_hi))
            if areas[behind].sum() > MAX_BEHIND_SHARE * weight:
                # What a window or a door shows of outside is no evidence against the wall it is in.
                wall_uz = np.stack([along, heights], axis=1)
                sample = np.flatnonzero(behind)
                sample = sample[::max(1, -(-len(sample) // AREA_SAMPLE_FACES))]  # every k-th face
                through = seen_through_openings(wall_uz, centroids[sample], cameras, direction, offset, u_axis)
                not_through = areas[sample][~through].sum() / max(areas[sample].sum(), 1e-12) * areas[behind].sum()
                if not_through > MAX_BEHIND_SHARE * weight:
                    continue  # furniture, or an inner wall with room behind it
            if len(cameras) and np.median(cameras @ direction) < offset:
                continue  # the cameras are behind it
            if len(cameras) and _seen_from_its_back(centroids[facing][near], areas[facing][near], cameras, direction, offset):
                if not _walked_through_an_opening(np.stack([along, heights], axis=1), cameras, direction, offset, u_axis):
                    seen_through.append((-direction, -offset, weight))
                continue
            if not _found_already(planes, direction, offset):  # its histogram can have a broad top
                planes.append(_wall(direction, offset, weight))
    for direction, offset, weight in seen_through:
        if not _found_already(planes, direction, offset):
            planes.append(_wall(direction, offset, weight))
    return planes, {"heading_deg": round(float(np.degrees(heading)), 2), "manhattan": bool(manhattan)}
