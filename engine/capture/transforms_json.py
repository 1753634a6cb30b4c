"""Loader for instant-ngp / nerfstudio `transforms.json` (format "transforms").

Intrinsics: shared keys at the top level, overridden per frame when a frame has its own (nerfstudio):
`fl_x`, `fl_y`, `cx`, `cy`, `w`, `h`; without `fl_x`, `camera_angle_x` (and `camera_angle_y` for
fy, else fy = fx) give the focal length; without `cx`/`cy` the principal point is the image centre;
without `w`/`h` the image's own size is used. When `w`/`h` differ from the photo by a uniform
scale (downsampled copies), K is scaled. Distortion `k1 k2 p1 p2 [k3]` (OpenCV model) is
undistorted into the cache (see `undistort.py`); fisheye/equirectangular cameras are refused.

Poses: `transform_matrix` is camera-to-world in OpenGL camera axes (x right, y up, z backward);
the y and z columns are negated to get OpenCV axes. The world frame is kept as given: instant-ngp's
colmap2nerf.py re-orients it to Z up, other tools may leave it Y up; gravity alignment is the poses
stage's job. `metric` is False (these files have arbitrary scale) unless the file has a top-level
`"metric": true` (written by our own tools) or the `metric=` option overrides it.

Frames whose photo is missing or whose matrix is absent, not finite or not a rotation are skipped
with one warning naming them (the instant-ngp fox lists 67 frames for 50 photos). Rotations that are
orthonormal only to a few digits (trackers' files) are made exact (`geometry.PoseRepairs`).
"""

from __future__ import annotations

import json
import math
from pathlib import Path
from typing import Any, Optional

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn
from .checks import SkippedPhotos, finish_capture, inspect_images
from .geometry import PoseRepairs, fit_intrinsics, opengl_to_opencv, parse_pose, pinhole
from .images import IMAGE_SUFFIXES, UnusableImage
from .model import Capture, Frame
from .naming import name_list
from .options import LoadOptions
from .undistort import undistort_capture

_INTRINSIC_KEYS = ("fl_x", "fl_y", "cx", "cy", "w", "h", "camera_angle_x", "camera_angle_y",
                   "k1", "k2", "k3", "k4", "p1", "p2", "camera_model", "is_fisheye")
_PINHOLE_MODELS = (None, "OPENCV", "PINHOLE", "SIMPLE_PINHOLE", "SIMPLE_RADIAL", "RADIAL")


def _read_json(path: Path) -> dict[str, Any]:
    try:
        data = json.loads(path.read_text(encoding="utf-8"))
    except OSError as error:
        raise CaptureError(f"cannot read {path}: {error.strerror or error}.") from error
    except ValueError as error:
        raise CaptureError(f"{path} is not valid JSON ({error}): fix or re-export it.") from error
    if not isinstance(data, dict) or not isinstance(data.get("frames"), list):
        raise CaptureError(f"{path} has no \"frames\" list: it is not an instant-ngp/nerfstudio transforms.json.")
    return data


def _resolve_image(base: Path, file_path: str) -> Optional[Path]:
    """The photo a frame names; NeRF-synthetic style paths without a suffix ("./train/r_0") get one."""
    candidate = base / file_path  # pathlib drops "./"; an absolute file_path replaces base
    if candidate.is_file():
        return candidate
    if not candidate.suffix:
        for suffix in IMAGE_SUFFIXES + (".PNG", ".JPG"):
            with_suffix = candidate.with_name(candidate.name + suffix)
            if with_suffix.is_file():
                return with_suffix
    return None


def _number(camera: dict[str, Any], key: str, source: Path) -> Optional[float]:
    value = camera.get(key)
    if value is None:
        return None
    try:
        number = float(value)
    except (TypeError, ValueError):
        number = math.nan
    if not math.isfinite(number):
        raise CaptureError(f"{source}: \"{key}\" is {value!r}, not a finite number: fix the file.")
    return number


def _camera_model(camera: dict[str, Any], source: Path) -> None:
    model = camera.get("camera_model")
    if camera.get("is_fisheye") or model not in _PINHOLE_MODELS:
        name = model or "fisheye (is_fisheye)"
        raise CaptureError(f"{source}: camera model {name} is not supported (only pinhole cameras with "
                           "OpenCV k1 k2 p1 p2 k3 distortion): undistort the images first, e.g. with "
                           "nerfstudio `ns-process-data` or COLMAP `image_undistorter`, and export a pinhole camera.")
    if _number(camera, "k4", source):
        raise CaptureError(f"{source}: distortion coefficient k4 is only used by fisheye models, which are not "
                           "supported: undistort the images first and export a pinhole camera.")


def _intrinsics(camera: dict[str, Any], image_size: tuple[int, int], image_path: Path,
                source: Path) -> tuple[np.ndarray, np.ndarray, Optional[str]]:
    """K (3, 3) for the photo as stored, distortion (5,) and an optional scaling warning."""
    _camera_model(camera, source)
    w, h = _number(camera, "w", source), _number(camera, "h", source)
    stated = (int(round(w)), int(round(h))) if w and h else image_size
    fx, fy = _number(camera, "fl_x", source), _number(camera, "fl_y", source)
    angle_x, angle_y = _number(camera, "camera_angle_x", source), _number(camera, "camera_angle_y", source)
    if fx is None:  # NeRF-synthetic style: field of view instead of focal length
        if not angle_x:
            raise CaptureError(f"{source} gives no focal length for {image_path.name}: add \"fl_x\" (pixels) or "
                               "\"camera_angle_x\" (radians).")
        fx = 0.5 * stated[0] / math.tan(0.5 * angle_x)
        if fy is None and angle_y:
            fy = 0.5 * stated[1] / math.tan(0.5 * angle_y)
    if fy is None:
        fy = fx
    cx, cy = _number(camera, "cx", source), _number(camera, "cy", source)
    K = pinhole(fx, fy, stated[0] / 2.0 if cx is None else cx, stated[1] / 2.0 if cy is None else cy)
    K, warning = fit_intrinsics(K, stated, image_size, image_path, str(source))
    dist = np.array([_number(camera, key, source) or 0.0 for key in ("k1", "k2", "p1", "p2", "k3")])
    return K, dist, warning


def load_transforms(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                    cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "transforms") from `path`: a transforms.json file or the folder holding it."""
    json_path = path / "transforms.json" if path.is_dir() else path
    data = _read_json(json_path)
    shared = {key: data[key] for key in _INTRINSIC_KEYS if key in data}

    skipped_missing, skipped_pose, entries = [], [], []
    repairs = PoseRepairs()
    for index, entry in enumerate(data["frames"]):
        label = str(entry.get("file_path", f"frame {index}")) if isinstance(entry, dict) else f"frame {index}"
        if not isinstance(entry, dict) or "transform_matrix" not in entry:
            skipped_pose.append(f"{label} (no transform_matrix)")
            continue
        try:
            pose = repairs.make_rigid(parse_pose(entry["transform_matrix"]), label)
        except (TypeError, ValueError) as error:
            skipped_pose.append(f"{label} ({error})")
            continue
        image_path = _resolve_image(json_path.parent, str(entry.get("file_path", "")))
        if image_path is None:
            skipped_missing.append(label)
            continue
        camera = {**shared, **{key: entry[key] for key in _INTRINSIC_KEYS if key in entry}}
        entries.append((image_path, opengl_to_opencv(pose), camera))

    warnings = []
    if skipped_missing:
        warnings.append(f"{len(skipped_missing)} frame(s) in {json_path.name} point at missing images, skipped: "
                        f"{name_list(skipped_missing)}")
    if skipped_pose:
        warnings.append(f"{len(skipped_pose)} frame(s) in {json_path.name} have no usable pose, skipped: "
                        f"{name_list(skipped_pose)}")
    if repairs.warning():
        warnings.append(f"{json_path.name}: {repairs.warning()}")
    if not entries:
        reasons = "; ".join(warnings) or "its frames list is empty"
        raise CaptureError(f"no usable frame in {json_path}: {reasons}. Check the file_path entries and matrices.")

    skipped = SkippedPhotos()
    infos = inspect_images([p for p, _, _ in entries], skipped, verify=options.verify_images, progress=progress,
                           cancel=cancel)
    frames, usable_infos, distortion, scale_warnings = [], [], {}, []
    for (image_path, pose, camera), info in zip(entries, infos):
        if info is None:
            continue
        try:
            K, dist, warning = _intrinsics(camera, info.size, image_path, json_path)
        except UnusableImage as error:  # another aspect ratio than the stated camera
            skipped.add(error)
            continue
        if warning and not scale_warnings:
            scale_warnings.append(warning)
        frames.append(Frame(image_path=image_path, width=info.width, height=info.height, K=K, pose=pose))
        usable_infos.append(info)
        distortion[image_path] = dist
    metric = options.metric if options.metric is not None else data.get("metric") is True
    capture = finish_capture(path, "transforms", frames, usable_infos, json_path, metric, warnings + scale_warnings,
                             skipped, what="posed photo")
    return undistort_capture(capture, distortion, options, progress, cancel)
