"""Blender cameras from a Capture's intrinsics and poses, exact to the pixel.

The conversion (checked in blender-notes.md section 6 to 0.0001 px against OpenCV):
- Blender camera = OpenCV camera rotated 180 deg about its x axis, so
  `matrix_world = pose @ diag(1, -1, -1, 1)`.
- Render resolution = photo size. fx != fy cannot be a per-camera setting in Blender, so it becomes the
  scene's pixel aspect (`pixel_aspect_y = fx / fy`, or `pixel_aspect_x = fy / fx`; Blender keeps both >= 1).
- Sensor fit by the larger aspect-corrected side; lens = fx * 36 / W (horizontal fit) or fy * 36 / H
  (vertical fit); shift_x = (W/2 - cx) * ax / m, shift_y = (cy - H/2) * ay / m with
  m = max(W * ax, H * ay).

Pixel convention: the engine's K puts pixel (0, 0) over [0, 1)^2 (COLMAP's convention), which is
also Blender's: the camera frame spans [0, W] x [0, H] with no half-pixel offset, so the formulas need
no +-0.5 correction. (K with integer pixel centres, OpenCV's habit, is converted by the loaders.)

Work is split in two so a bad frame cannot leave half-built cameras: `plan_capture_cameras` validates
and computes everything from the Capture alone (no bpy), then `apply_camera_plan` writes Blender data.

Each camera object stores its frame's exact float64 K, pose and image path as custom properties, so the
posed capture can be read back from the scene after the .blend is saved and reopened
(`posed_capture_from_scene`), without re-running structure from motion.
"""

from __future__ import annotations

import json
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

import bpy
import numpy as np

from ..engine.capture import Capture, Frame
from ..engine.capture.model import SensorDepth
from ..engine.capture.geometry import rigid_pose
from ..engine.errors import CaptureError, PoseError
from .point_cloud import scene_points
from .scene_objects import ensure_capture_collection, find_capture_collection, place_camera

SENSOR_MM = 36.0
# Custom property names: per-camera keys hold the frame's exact data (IDProperty float arrays are
# float64, so nothing is lost).
PROP_FRAME = "vortx_frame"
PROP_IMAGE = "vortx_image"
PROP_SIZE = "vortx_size"
PROP_K = "vortx_K"
PROP_POSE = "vortx_pose"
PROP_DEPTH = "vortx_depth"
PROP_SENSOR_DEPTH = "vortx_sensor_depth"  # JSON of engine.capture.model.SensorDepth: a phone's depth, used by Reconstruct

# OpenCV camera axes (x right, y down, z forward) -> Blender camera axes (x right, y up, looks down -z).
CV_TO_BLENDER_CAMERA = np.diag([1.0, -1.0, -1.0, 1.0])

# Blender clamps camera settings to these ranges; values outside them would silently change the
# projection, so they are rejected with a message instead.
_LENS_MIN_MM = 1.0
_SHIFT_LIMIT = 10.0
_PIXEL_ASPECT_MAX = 200.0
_ASPECT_TOLERANCE = 1e-6


@dataclass(frozen=True)
class PixelAspect:
    x: float = 1.0
    y: float = 1.0


@dataclass(frozen=True)
class CameraParams:
    """Blender Camera datablock settings for one frame (render resolution and aspect are scene-wide)."""

    lens: float
    sensor_fit: str  # "HORIZONTAL" or "VERTICAL"
    shift_x: float
    shift_y: float
    sensor_width: float = SENSOR_MM
    sensor_height: float = SENSOR_MM


@dataclass(frozen=True)
class CameraSpec:
    name: str
    frame_index: int
    frame: Frame
    params: CameraParams
    matrix_world: np.ndarray  # (4, 4) float64, Blender camera axes


@dataclass
class CameraPlan:
    resolution: tuple[int, int]
    pixel_aspect: PixelAspect
    cameras: list[CameraSpec]
    warnings: list[str] = field(default_factory=list)


def pixel_aspect_from_intrinsics(K: np.ndarray) -> PixelAspect:
    """Scene pixel aspect that makes Blender's fy / fx equal the photo's (both values kept >= 1)."""
    ratio = float(K[0, 0]) / float(K[1, 1])
    if abs(ratio - 1.0) <= _ASPECT_TOLERANCE:
        return PixelAspect(1.0, 1.0)
    return PixelAspect(1.0, ratio) if ratio > 1.0 else PixelAspect(1.0 / ratio, 1.0)


def camera_params_from_intrinsics(K: np.ndarray, width: int, height: int, aspect: PixelAspect) -> CameraParams:
    """Blender lens / sensor fit / shift reproducing pinhole K for a width x height render with `aspect`."""
    fx, fy, cx, cy = float(K[0, 0]), float(K[1, 1]), float(K[0, 2]), float(K[1, 2])
    # Blender picks the fitted side by its aspect-corrected length; we pick it explicitly the same way
    # so the formulas below are the ones Blender evaluates (and AUTO's tie-breaking never matters).
    horizontal = width * aspect.x >= height * aspect.y
    m = max(width * aspect.x, height * aspect.y)
    lens = fx * SENSOR_MM / width if horizontal else fy * SENSOR_MM / height
    return CameraParams(
        lens=lens,
        sensor_fit="HORIZONTAL" if horizontal else "VERTICAL",
        shift_x=(width / 2.0 - cx) * aspect.x / m,
        shift_y=(cy - height / 2.0) * aspect.y / m,
    )


def blender_matrix_from_pose(pose: np.ndarray) -> np.ndarray:
    """Blender camera matrix_world from an OpenCV camera-to-world pose."""
    return np.asarray(pose, dtype=np.float64) @ CV_TO_BLENDER_CAMERA


def _validate_intrinsics(frame: Frame) -> None:
    K = frame.K
    if K is None:
        raise CaptureError(f"frame {frame.name} has a pose but no intrinsics (K); the capture loader should provide both")
    K = np.asarray(K, dtype=np.float64)
    if K.shape != (3, 3) or not np.all(np.isfinite(K)):
        raise CaptureError(f"frame {frame.name}: intrinsics K must be a finite 3x3 matrix, got {K.tolist()}")
    if K[0, 0] <= 0 or K[1, 1] <= 0:
        raise CaptureError(f"frame {frame.name}: focal lengths must be positive, got fx={K[0, 0]}, fy={K[1, 1]}")
    if frame.width <= 0 or frame.height <= 0:
        raise CaptureError(f"frame {frame.name}: image size {frame.width}x{frame.height} is not valid")


def _validate_pose(frame: Frame) -> None:
    pose = np.asarray(frame.pose, dtype=np.float64)
    if pose.shape != (4, 4) or not np.all(np.isfinite(pose)):
        raise PoseError(f"frame {frame.name}: the camera pose must be a finite 4x4 matrix (it contains NaN/inf or has shape {pose.shape})")
    if not np.allclose(pose[3], [0.0, 0.0, 0.0, 1.0], atol=1e-6):
        raise PoseError(f"frame {frame.name}: the camera pose's last row must be [0, 0, 0, 1], got {pose[3].tolist()}")
    # A scaled or sheared rotation would become a scaled Blender camera whose projection no longer
    # matches the photo. The loaders make near-rotations exact; this is the same test they apply
    # (one tolerance for the CLI, Blender and the batch script).
    try:
        rigid_pose(pose)
    except ValueError as error:
        raise PoseError(f"frame {frame.name}: the camera pose's rotation is not a proper rotation matrix ({error})") from error


def plan_capture_cameras(capture: Capture) -> CameraPlan:
    """Validate every posed frame and compute its Blender camera, touching no Blender data.

    Raises CaptureError / PoseError naming the first bad frame.
    """
    posed = [(index, frame) for index, frame in enumerate(capture.frames) if frame.pose is not None]
    warnings: list[str] = []
    if not posed:
        return CameraPlan(resolution=capture.resolution, pixel_aspect=PixelAspect(), cameras=[], warnings=warnings)
    for _, frame in posed:
        _validate_intrinsics(frame)
        _validate_pose(frame)

    sizes = {(frame.width, frame.height) for _, frame in posed}
    if len(sizes) > 1:
        raise CaptureError(f"posed frames have different image sizes {sorted(sizes)}; one capture must use one resolution")
    width, height = sizes.pop()

    # Pixel aspect is a scene setting shared by all cameras; use the median fx/fy and say so when
    # frames disagree (their projections are then off by the difference).
    ratios = np.array([frame.K[0, 0] / frame.K[1, 1] for _, frame in posed], dtype=np.float64)
    median = float(np.median(ratios))
    aspect = pixel_aspect_from_intrinsics(np.array([[median, 0, 0], [0, 1.0, 0], [0, 0, 1]]))
    if max(aspect.x, aspect.y) > _PIXEL_ASPECT_MAX:
        raise CaptureError(f"fx/fy = {median:.4g} is outside what Blender's pixel aspect can represent")
    if np.any(np.abs(ratios / median - 1.0) > 1e-4):
        warnings.append(f"frames have different fx/fy ratios ({ratios.min():.5f}..{ratios.max():.5f}); Blender cameras use {median:.5f}")

    cameras: list[CameraSpec] = []
    for index, frame in posed:
        params = camera_params_from_intrinsics(np.asarray(frame.K, dtype=np.float64), width, height, aspect)
        if params.lens < _LENS_MIN_MM:
            raise CaptureError(f"frame {frame.name}: the focal length is too short for a Blender camera (field of view near 180 deg)")
        if abs(params.shift_x) > _SHIFT_LIMIT or abs(params.shift_y) > _SHIFT_LIMIT:
            raise CaptureError(f"frame {frame.name}: the principal point lies far outside the image; check the intrinsics")
        name = f"VoRTX {Path(frame.image_path).stem}"[:63]
        cameras.append(CameraSpec(name, index, frame, params, blender_matrix_from_pose(frame.pose)))
    return CameraPlan(resolution=(width, height), pixel_aspect=aspect, cameras=cameras, warnings=warnings)


# ----------------------------------------------------------------------------------------------
# Blender side


def is_capture_camera(obj: "bpy.types.Object") -> bool:
    return obj.type == "CAMERA" and PROP_FRAME in obj


def remove_capture_cameras(collection: "bpy.types.Collection") -> None:
    """Delete the cameras we created in `collection`; anything else the user put there stays."""
    for obj in [o for o in collection.objects if is_capture_camera(o)]:
        data = obj.data
        bpy.data.objects.remove(obj, do_unlink=True)
        if data is not None and data.users == 0:
            bpy.data.cameras.remove(data)


def apply_camera_plan(scene: "bpy.types.Scene", plan: CameraPlan) -> list["bpy.types.Object"]:
    """Replace the scene's capture cameras with `plan`'s and set the render format to match. The
    cameras are placed in the coordinates the scene shows (scene_objects.py)."""
    collection = ensure_capture_collection(scene)
    remove_capture_cameras(collection)

    objects = []
    for spec in plan.cameras:
        data = bpy.data.cameras.new(spec.name)
        data.sensor_fit = spec.params.sensor_fit
        data.sensor_width = spec.params.sensor_width
        data.sensor_height = spec.params.sensor_height
        data.lens = spec.params.lens
        data.shift_x = spec.params.shift_x
        data.shift_y = spec.params.shift_y
        data.clip_start = 0.01
        data.clip_end = 1000.0
        data.display_size = 0.1  # rooms are a few metres across; default 1 m frustums would clutter them
        obj = bpy.data.objects.new(spec.name, data)
        place_camera(obj, scene, spec.matrix_world)
        frame = spec.frame
        obj[PROP_FRAME] = spec.frame_index
        obj[PROP_IMAGE] = str(frame.image_path)
        obj[PROP_SIZE] = [int(frame.width), int(frame.height)]
        obj[PROP_K] = np.asarray(frame.K, dtype=np.float64).ravel().tolist()
        obj[PROP_POSE] = np.asarray(frame.pose, dtype=np.float64).ravel().tolist()
        if frame.depth_path is not None:
            obj[PROP_DEPTH] = str(frame.depth_path)
        if frame.sensor_depth is not None:
            obj[PROP_SENSOR_DEPTH] = json.dumps(frame.sensor_depth.to_dict())
        collection.objects.link(obj)
        objects.append(obj)

    if plan.cameras:
        render = scene.render
        render.resolution_x, render.resolution_y = plan.resolution
        render.resolution_percentage = 100
        render.pixel_aspect_x = plan.pixel_aspect.x
        render.pixel_aspect_y = plan.pixel_aspect.y
        if scene.camera is None:  # never replace a camera the user chose
            scene.camera = objects[0]
    return objects


def capture_cameras(scene: "bpy.types.Scene") -> list["bpy.types.Object"]:
    """The scene's capture cameras in frame order (the order of `posed_capture_from_scene`'s frames)."""
    collection = find_capture_collection(scene)
    if collection is None:
        return []
    return sorted((o for o in collection.objects if is_capture_camera(o)), key=lambda o: int(o[PROP_FRAME]))


def move_capture_cameras(scene: "bpy.types.Scene", poses: list[np.ndarray]) -> None:
    """Give the capture cameras (frame order) new camera-to-world `poses` (4, 4), keeping the objects
    (their names, selection and anything the user attached to them)."""
    for obj, pose in zip(capture_cameras(scene), poses, strict=True):
        obj[PROP_POSE] = np.asarray(pose, dtype=np.float64).ravel().tolist()
        place_camera(obj, scene, blender_matrix_from_pose(pose))


def build_capture_cameras(scene: "bpy.types.Scene", capture: Capture) -> tuple[list["bpy.types.Object"], list[str]]:
    """Validate, then create one camera per posed frame. Returns (camera objects, warnings)."""
    plan = plan_capture_cameras(capture)
    return apply_camera_plan(scene, plan), plan.warnings


def posed_capture_from_scene(scene: "bpy.types.Scene") -> Optional[Capture]:
    """The posed frames of the scene's capture, rebuilt exactly from the camera objects' stored data.

    The stored float64 K and pose are used rather than the cameras' transforms, which are float32 and
    would be moved by accident as often as on purpose. The sparse points come from the point cloud
    object, when there is one. Returns None when there are no capture cameras.
    """
    objects = capture_cameras(scene)
    if not objects:
        return None
    frames = []
    for obj in objects:
        width, height = (int(v) for v in obj[PROP_SIZE])
        depth = obj.get(PROP_DEPTH)
        sensor = obj.get(PROP_SENSOR_DEPTH)
        frames.append(
            Frame(
                image_path=Path(obj[PROP_IMAGE]),
                width=width,
                height=height,
                K=np.array(obj[PROP_K], dtype=np.float64).reshape(3, 3),
                pose=np.array(obj[PROP_POSE], dtype=np.float64).reshape(4, 4),
                depth_path=Path(depth) if depth else None,
                sensor_depth=SensorDepth.from_dict(json.loads(sensor)) if sensor else None,
            )
        )
    settings = scene.vortx
    capture = Capture(
        root=Path(settings.capture_path),
        format=settings.capture_format,
        frames=frames,
        metric=bool(settings.poses_metric),
    )
    points, colours = scene_points(scene)
    return capture if points is None else capture.with_points(points, colours)

