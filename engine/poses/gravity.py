"""Gravity and metric scale for SfM poses: +Z up, floor at z = 0, metres.

SfM returns a world with an arbitrary orientation, origin and scale. VoRTX expects metres with
gravity along -Z, so we
1. rotate the world so the cameras' mean "up" becomes +Z. People hold phones roughly level, so
   the mean of the cameras' up vectors (OpenCV camera up is -y, i.e. -R[:, 1] in the world) is a
   good gravity estimate; tilts up and down cancel out in the mean;
2. find the floor as a low percentile of the sparse points' heights (robust to a few stray points
   below the floor), then scale so the median camera height above it is `camera_height`
   (a hand-held phone is ~1.5 m up), or scale from a known distance between two cameras;
3. translate so the floor is at z = 0, which puts the room on Blender's ground plane.
"""

from __future__ import annotations

from dataclasses import dataclass, field, replace
from pathlib import Path
from typing import Optional

import numpy as np

from ..capture.model import Capture, Frame
from ..errors import PoseError
from .align import Similarity

FLOOR_PERCENTILE = 2.0  # of point heights; tolerates up to ~2 % of points below the true floor
MIN_FLOOR_POINTS = 20  # fewer points below the cameras than this: the floor is not seen


@dataclass(frozen=True)
class KnownDistance:
    """The user measured the distance between the cameras of two frames (by file name)."""

    frame_a: str
    frame_b: str
    metres: float


@dataclass
class Alignment:
    capture: Capture  # the moved capture (frames without a pose stay without one)
    similarity: Similarity  # what was applied: x_new = s R x + t
    points: Optional[np.ndarray]  # (N, 3) the given points moved the same way, or None
    scale_source: str  # "camera height", "known distance", "metric capture", "unknown"
    description: str  # one line for reports
    warnings: list[str] = field(default_factory=list)


def mean_up_direction(cam_to_world: np.ndarray) -> np.ndarray:
    """(N, 4, 4) camera-to-world (OpenCV axes) -> (3,) unit mean of the cameras' up vectors (-y)."""
    ups = -cam_to_world[:, :3, 1]
    mean = ups.mean(axis=0)
    norm = np.linalg.norm(mean)
    if norm < 1e-6:
        raise PoseError("cannot find 'up': the cameras' up directions cancel out (cameras pointing every way)")
    return mean / norm


def rotation_taking(a: np.ndarray, b: np.ndarray) -> np.ndarray:
    """The smallest rotation (3, 3) taking unit vector a onto unit vector b (Rodrigues).

    Smallest, so the heading (yaw) of the SfM world is kept: the scene does not spin around Z.
    """
    v = np.cross(a, b)
    c = float(np.dot(a, b))
    if c < -1.0 + 1e-12:
        # Opposite vectors: any half-turn about an axis perpendicular to a will do.
        axis = np.cross(a, [1.0, 0.0, 0.0])
        if np.linalg.norm(axis) < 1e-6:
            axis = np.cross(a, [0.0, 1.0, 0.0])
        axis /= np.linalg.norm(axis)
        return 2.0 * np.outer(axis, axis) - np.eye(3)
    vx = np.array([[0.0, -v[2], v[1]], [v[2], 0.0, -v[0]], [-v[1], v[0], 0.0]])
    return np.eye(3) + vx + vx @ vx / (1.0 + c)


def floor_height(point_z: Optional[np.ndarray], camera_z: np.ndarray) -> Optional[float]:
    """Height of the floor from points' z (N,) in a gravity-aligned world, or None when not seen.

    The floor must lie below the cameras; points above the median camera height say nothing
    about it, and a percentile taken over too few points below the cameras is noise.
    """
    if point_z is None or len(point_z) == 0:
        return None
    below = point_z[point_z < np.median(camera_z)]
    if len(below) < MIN_FLOOR_POINTS:
        return None
    return float(np.percentile(below, FLOOR_PERCENTILE))


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
    camera_height: float = 1.5,
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
    rotation = rotation_taking(mean_up_direction(poses), np.array([0.0, 0.0, 1.0]))
    rotate = Similarity(rotation, np.zeros(3), 1.0)
    warnings: list[str] = []

    if capture.metric:
        similarity = rotate
        scale_source = "metric capture"
        description = "metric capture: rotated to Z up, scale and position kept"
    else:
        camera_z = (poses[:, :3, 3] @ rotation.T)[:, 2]
        point_z = None if points is None else (np.asarray(points, dtype=np.float64) @ rotation.T)[:, 2]
        floor = floor_height(point_z, camera_z)
        if known_distance is not None:
            a = _frame_centre(capture, known_distance.frame_a)
            b = _frame_centre(capture, known_distance.frame_b)
            separation = float(np.linalg.norm(a - b))
            if separation < 1e-9:
                raise PoseError(
                    f"known distance: frames {known_distance.frame_a!r} and {known_distance.frame_b!r} "
                    "were placed at the same spot; pick two frames taken further apart"
                )
            scale = known_distance.metres / separation
            scale_source = "known distance"
            description = (
                f"scale from {known_distance.frame_a} <-> {known_distance.frame_b} = {known_distance.metres:g} m"
            )
        elif floor is not None:
            height = float(np.median(camera_z)) - floor
            scale = camera_height / height
            scale_source = "camera height"
            description = f"scale from a camera height of {camera_height:g} m above the floor seen in the points"
        else:
            scale = 1.0
            scale_source = "unknown"
            description = "scale unknown (no floor points): SfM units kept"
            warnings.append(
                "the floor is not visible in the sparse points, so the scale is unknown; "
                "give a known distance between two photos to get metres"
            )
        # Floor at z = 0. Without a visible floor, assume the cameras are camera_height above it
        # (in metres when the scale is known, else in SfM units: only the origin is a guess then).
        floor_z = floor if floor is not None else float(np.median(camera_z)) - camera_height / scale
        similarity = rotate.then(Similarity(np.eye(3), np.array([0.0, 0.0, -scale * floor_z]), scale))

    frames = [f if f.pose is None else _moved(f, similarity) for f in capture.frames]
    moved_points = None if points is None else similarity.apply_points(points)
    metric = capture.metric or scale_source in ("camera height", "known distance")
    aligned = capture.with_frames(frames, metric=metric)
    description += f" (scale x{similarity.scale:.4g})"
    return Alignment(aligned, similarity, moved_points, scale_source, description, warnings)


def _moved(frame: Frame, similarity: Similarity) -> Frame:
    assert frame.pose is not None
    return replace(frame, pose=similarity.apply_pose(frame.pose))
