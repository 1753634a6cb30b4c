"""Gravity and metric scale for SfM poses: +Z up, floor at z = 0, metres.

SfM returns a world with an arbitrary orientation, origin and scale. VoRTX expects metres with
gravity along -Z, so we
1. rotate the world so that up becomes +Z: up from the photos' vertical lines
   (`engine/capture/vertical_lines.py`) when enough are seen, else the mean of the cameras' up
   vectors (OpenCV camera up is -y, i.e. -R[:, 1] in the world), which leans however the phone was held;
2. find the floor as a plane in the sparse points below the cameras (RANSAC along gravity,
   `floor.py`); when the plane is well supported its normal refines gravity if the lines gave
   none, and is checked against the lines' up if they did (a disagreement is a warning). The median camera
   height above it, set equal to `camera_height` (`camera_height.py`: a hand-held phone), gives the
   scale, unless a known distance between two cameras or two 3D points is given;
   when no floor plane is found, the lowest points (a low percentile of the heights) stand in
   for the floor and the report says so; with no points below the cameras the scale is unknown;
3. translate so the floor is at z = 0, which puts the room on Blender's ground plane.

Public API (also used by Blender's Set Scale and the CLI's `--known-distance`):
- `align_gravity_and_scale(capture, camera_height=DEFAULT_CAMERA_HEIGHT_M, known_distance=None, points=None,
  align_metric=False) -> Alignment` (fields: capture, similarity, points, scale_source,
  description, warnings, floor, floor_method, camera_height_units);
- `KnownDistance(a, b, metres)`: each end a frame's file name (its camera centre) or a 3D point
  (3 floats, in the capture's world before alignment);
- `scale_from_known_distance(point_a, point_b, metres) -> float`: the factor that makes the two
  points `metres` apart;
- `rescale_capture(capture, factor, points=None) -> Rescaled`: poses (and sparse points) scaled
  about the world origin; the capture is marked metric.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional, Sequence, Union

import numpy as np

from ..capture.model import Capture, Frame
from ..errors import PoseError
from ..geometry.cameras import mean_up_direction, rotation_taking  # noqa: F401 (also this module's API)
from .align import Similarity
from .camera_height import DEFAULT_CAMERA_HEIGHT_M
from .floor import GRAVITY_MIN_INLIERS, MIN_FLOOR_POINTS, FloorPlane, find_floor_plane
from ..capture.vertical_lines import up_from_vertical_lines

# Vertical lines measure up to a tenth of a degree (0.06-0.08 deg on the corridor's ARKit poses and the
# demo room's true ones); a well-supported floor plane more than this far from them is reported.
MAX_FLOOR_LINES_DISAGREEMENT_DEG = 2.0
FLOOR_PERCENTILE = 2.0  # fallback floor: this percentile of the heights below the cameras

Endpoint = Union[str, Sequence[float], np.ndarray]  # a frame's file name, or a 3D point (3,)


@dataclass(frozen=True)
class KnownDistance:
    """The user measured the distance between two things seen in the capture.

    `a` and `b` are each a frame's file name (the distance is between the two cameras) or a 3D
    point (3,) in the capture's current world, e.g. two SfM points or two mesh vertices.
    """

    a: Endpoint
    b: Endpoint
    metres: float

    def describe(self) -> str:
        return f"{_endpoint_text(self.a)} <-> {_endpoint_text(self.b)} = {self.metres:g} m"


@dataclass
class Alignment:
    capture: Capture  # the moved capture (frames without a pose stay without one)
    similarity: Similarity  # what was applied: x_new = s R x + t
    points: Optional[np.ndarray]  # (N, 3) the given points moved the same way, or None
    scale_source: str  # "camera height", "known distance", "metric capture", "unknown"
    description: str  # one line for reports: the scale, its source and the numbers behind it
    warnings: list[str] = field(default_factory=list)
    # The floor plane found, if any, in SfM units in the final Z-up orientation (before the scale and
    # the shift that puts it at z = 0).
    floor: Optional[FloorPlane] = None
    # How the floor was placed: "plane" (found in the points), "lowest points" (no plane: the
    # lowest points stand in), "assumed" (no points below the cameras: camera_height below them),
    # "" (metric capture, not searched).
    floor_method: str = ""
    camera_height_units: Optional[float] = None  # median camera height above the floor, SfM units


@dataclass
class Rescaled:
    capture: Capture  # poses scaled about the origin, marked metric
    points: Optional[np.ndarray]  # (N, 3) the given points scaled the same way, or None
    factor: float


def lowest_points_height(point_z: Optional[np.ndarray], camera_z: np.ndarray) -> Optional[float]:
    """Fallback floor height: a low percentile of the points' z (N,) below the cameras, or None.

    Points above the median camera height say nothing about the floor, and a percentile taken
    over too few points below the cameras is noise.
    """
    if point_z is None or len(point_z) == 0:
        return None
    below = point_z[point_z < np.median(camera_z)]
    if len(below) < MIN_FLOOR_POINTS:
        return None
    return float(np.percentile(below, FLOOR_PERCENTILE))


def scale_from_known_distance(point_a: np.ndarray, point_b: np.ndarray, metres: float) -> float:
    """The factor that makes `point_a` and `point_b` (3,) `metres` apart after scaling."""
    if not np.isfinite(metres) or metres <= 0:
        raise PoseError(f"known distance must be a positive number of metres, got {metres}")
    a, b = np.asarray(point_a, dtype=np.float64).reshape(3), np.asarray(point_b, dtype=np.float64).reshape(3)
    separation = float(np.linalg.norm(a - b))
    if not np.isfinite(separation) or separation < 1e-9:
        raise PoseError("known distance: the two picked points are at the same spot; pick two points further apart")
    return metres / separation


def rescale_capture(capture: Capture, factor: float, points: Optional[np.ndarray] = None) -> Rescaled:
    """Scale the capture's camera positions (and `points` (N, 3)) by `factor` about the world origin.

    Rotations are unchanged. The origin is the fixed point, so a floor at z = 0 stays there.
    The capture is marked metric: a known distance is a statement in metres.
    """
    if not np.isfinite(factor) or factor <= 0:
        raise PoseError(f"scale factor must be a positive number, got {factor}")
    scale = Similarity(np.eye(3), np.zeros(3), float(factor))
    frames = [f if f.pose is None else _moved(f, scale) for f in capture.frames]
    moved = None if points is None else scale.apply_points(points)
    return Rescaled(capture.with_frames(frames, metric=True), moved, float(factor))


def endpoint_position(capture: Capture, endpoint: Endpoint) -> np.ndarray:
    """A known-distance end as a 3D point (3,) in the capture's world: a frame's camera centre or the point itself."""
    if isinstance(endpoint, (str, Path)):
        return _frame_centre(capture, str(endpoint))
    point = np.asarray(endpoint, dtype=np.float64)
    if point.shape != (3,) or not np.all(np.isfinite(point)):
        raise PoseError(f"known distance: {endpoint!r} is neither a frame name nor a 3D point (x, y, z)")
    return point


def _endpoint_text(endpoint: Endpoint) -> str:
    if isinstance(endpoint, (str, Path)):
        return str(endpoint)
    return "(" + ", ".join(f"{float(v):.3g}" for v in np.asarray(endpoint).reshape(-1)) + ")"


def _frame_centre(capture: Capture, name: str) -> np.ndarray:
    matches = [f for f in capture.frames if f.name == name]
    if not matches:  # undistorted copies may have another suffix (IMG_1.jpeg -> IMG_1.jpg)
        matches = [f for f in capture.frames if f.image_path.stem == Path(name).stem]
    if not matches:
        raise PoseError(f"known distance: there is no frame named {name!r} in {capture.root}")
    if matches[0].pose is None:
        raise PoseError(f"known distance: frame {name!r} has no camera pose (it was not registered); pick another")
    return matches[0].pose[:3, 3]


def align_gravity_and_scale(
    capture: Capture,
    camera_height: float = DEFAULT_CAMERA_HEIGHT_M,
    known_distance: Optional[KnownDistance] = None,
    points: Optional[np.ndarray] = None,
    align_metric: bool = False,
) -> Alignment:
    """Move the posed frames (and `points` (N, 3)) to a Z-up, floor-at-zero, metric world.

    Metric captures (`capture.metric`) are returned untouched unless `align_metric`, which then
    only rotates them to Z up (their scale and floor are trusted). The returned capture is marked
    metric whenever a scale was set.
    """
    posed = [f for f in capture.frames if f.pose is not None]
    if not posed:
        raise PoseError(f"no frame of {capture.root} has a camera pose, so there is nothing to align")
    if camera_height <= 0:
        raise PoseError(f"camera height must be positive, got {camera_height} m")
    if known_distance is not None and known_distance.metres <= 0:
        raise PoseError(f"known distance must be positive, got {known_distance.metres} m")
    if capture.metric and not align_metric:
        return Alignment(capture, Similarity.identity(), points, "metric capture", "metric capture: poses kept as they are")

    poses = np.stack([f.pose for f in posed])
    mean_up = mean_up_direction(poses)
    if capture.metric:
        rotation = rotation_taking(mean_up, np.array([0.0, 0.0, 1.0]))
        return _finish(capture, Similarity(rotation, np.zeros(3), 1.0), points, "metric capture",
                       "metric capture: rotated to Z up, scale and position kept", [], None, "", None)

    # Hand-held cameras' mean up leans by however the phone was held (10 deg and more looking down);
    # the photos' vertical lines measure gravity itself.
    lines = up_from_vertical_lines(posed, mean_up)
    rotation = rotation_taking(lines.up if lines is not None else mean_up, np.array([0.0, 0.0, 1.0]))
    warnings: list[str] = []
    centres = poses[:, :3, 3] @ rotation.T
    moved_points = None if points is None else np.asarray(points, dtype=np.float64).reshape(-1, 3) @ rotation.T
    search = find_floor_plane(moved_points, centres)
    gravity_note = f"; {lines.describe()}" if lines is not None else ""
    if search.plane is not None and search.plane.inliers >= GRAVITY_MIN_INLIERS:
        tilt = search.plane.tilt_deg
        if lines is not None:
            if tilt > MAX_FLOOR_LINES_DISAGREEMENT_DEG:
                warnings.append(f"the floor plane's normal is {tilt:.1f} deg from the up the vertical lines give: a "
                                "sloping floor, or a plane that is not the floor; up kept from the lines, check the "
                                "floor in the result")
            else:
                gravity_note += f", the floor's normal agrees within {tilt:.1f} deg"
        else:
            # A floor seen by many points measures "up" better than the cameras' mean up. Search again
            # in the corrected frame: "below the cameras" and the inlier band both depend on where up is.
            refine = rotation_taking(search.plane.normal, np.array([0.0, 0.0, 1.0]))
            rotation = refine @ rotation
            centres, moved_points = centres @ refine.T, moved_points @ refine.T
            search = find_floor_plane(moved_points, centres)
            if tilt >= 0.05:
                gravity_note = f"; gravity refined by the floor's normal ({tilt:.1f} deg from the cameras' mean up)"
    plane = search.plane
    camera_z = float(np.median(centres[:, 2]))

    if plane is not None:
        height = float(np.median(plane.heights(centres)))
        floor_z = camera_z - height
        floor_method = "plane"
        floor_text = (f"floor plane from {plane.inliers} points (RANSAC inliers {100 * plane.inlier_share:.0f} % "
                      f"of the {plane.candidates} points below the cameras), median camera height {height:.3g} units")
    else:
        lowest = lowest_points_height(None if moved_points is None else moved_points[:, 2], centres[:, 2])
        height = None if lowest is None else camera_z - lowest
        floor_z = lowest
        floor_method = "lowest points" if lowest is not None else "assumed"
        if lowest is not None:
            floor_text = (f"no floor plane found in the sparse points ({search.reason}): the lowest points are taken "
                          f"as the floor, median camera height {height:.3g} units")
        else:
            floor_text = f"no floor found in the sparse points ({search.reason})"

    if known_distance is not None:
        scale = scale_from_known_distance(endpoint_position(capture, known_distance.a),
                                          endpoint_position(capture, known_distance.b), known_distance.metres)
        scale_source = "known distance"
        description = f"scale from a known distance {known_distance.describe()} -> scaled x{scale:.3g}; {floor_text}"
        if floor_method != "plane":
            warnings.append(f"{floor_text}; the floor (z = 0) is only a guess")
    elif height is not None and height > 0:
        scale = camera_height / height
        scale_source = "camera height"
        description = f"{floor_text} -> scaled x{scale:.3g} to {camera_height:g} m"
        if floor_method == "lowest points":
            warnings.append(
                f"no floor plane found in the sparse points ({search.reason}): the scale from the {camera_height:g} m "
                "camera height assumes the lowest points lie on the floor, so the size may be off; check it, or set "
                "the scale from a known distance"
            )
    else:
        scale = 1.0
        scale_source = "unknown"
        description = f"{floor_text}: scale unknown, SfM units kept"
        warnings.append(f"{floor_text}, so the scale is unknown; give a known distance between two photos or "
                        "two points to get metres")
    description += gravity_note
    # Floor at z = 0. Without a visible floor, assume the cameras are camera_height above it
    # (in metres when the scale is known, else in SfM units: only the origin is a guess then).
    if floor_z is None:
        floor_z = camera_z - camera_height / scale
    similarity = Similarity(rotation, np.zeros(3), 1.0).then(Similarity(np.eye(3), np.array([0.0, 0.0, -scale * floor_z]), scale))
    return _finish(capture, similarity, points, scale_source, description, warnings, search.plane, floor_method, height)


# A hand-held walk keeps the camera at about one height over a level floor (the 3D Scanner App
# corridor's ARKit poses: 2.4 cm spread over 146 photos, 6 cm between stretches); a model bent at a fast
# turn puts whole stretches metres up or down (two SfM runs of its photos alone: 3.1 and 8.2 m between
# the median heights of 15-photo stretches, 0.6 and 1.9 m mean camera error).
BENT_WALK_STRETCH = 15  # photos, in capture order
BENT_WALK_HEIGHT_M = 1.0  # between two stretches' median heights: more is no hand-held walk on one floor


def bent_walk_warning(heights: np.ndarray, names: list[str]) -> Optional[str]:
    """A warning when the camera heights (N,) of a capture's posed photos (in capture order, named
    `names`) differ between stretches of the walk by more than BENT_WALK_HEIGHT_M; None otherwise or
    when there are too few photos for two stretches."""
    n, step = BENT_WALK_STRETCH, max(1, BENT_WALK_STRETCH // 3)
    if len(heights) < 2 * n:
        return None
    medians = np.array([np.median(heights[i:i + n]) for i in range(0, len(heights) - n + 1, step)])
    low, high = int(np.argmin(medians)) * step, int(np.argmax(medians)) * step
    spread = float(medians.max() - medians.min())
    if spread <= BENT_WALK_HEIGHT_M:
        return None
    return (f"the camera heights differ by {spread:.1f} m between photos {names[low]}..{names[low + n - 1]} and "
            f"{names[high]}..{names[high + n - 1]}: a hand-held walk over one floor stays within a few decimetres, so "
            "the poses are probably bent (a fast turn or a blurred photo joined wrongly); check the cameras, retake "
            "that turn slowly, or use the phone app's own poses")


def _finish(
    capture: Capture,
    similarity: Similarity,
    points: Optional[np.ndarray],
    scale_source: str,
    description: str,
    warnings: list[str],
    floor: Optional[FloorPlane],
    floor_method: str,
    height_units: Optional[float],
) -> Alignment:
    frames = [f if f.pose is None else _moved(f, similarity) for f in capture.frames]
    moved_points = None if points is None else similarity.apply_points(points)
    # Over a floor that was found, not for a phone's own tracking or a capture with no floor (a photographer
    # circling an object on a wall, the fox, moves the camera a metre and more up and down).
    if floor_method == "plane" and scale_source != "metric capture":
        posed = [f for f in frames if f.pose is not None]
        bent = bent_walk_warning(np.array([f.pose[2, 3] for f in posed]), [f.name for f in posed])
        if bent is not None:
            warnings = [*warnings, bent]
    metric = capture.metric or scale_source in ("camera height", "known distance")
    aligned = capture.with_frames(frames, metric=metric)
    return Alignment(aligned, similarity, moved_points, scale_source, description, warnings, floor, floor_method,
                     height_units)


def _moved(frame: Frame, similarity: Similarity) -> Frame:
    assert frame.pose is not None
    return replace(frame, pose=similarity.apply_pose(frame.pose))
