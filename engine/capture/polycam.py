"""Loader for Polycam's "raw data" export (format "polycam"), an iPhone/iPad app (LiDAR or Room mode,
with Developer mode on), as the app's own specification describes it (github.com/PolyCam/polyform,
README "Polycam's data format" and polyform/core/capture_folder.py):

    keyframes/images/T.jpg              photos; T is the keyframe's timestamp in microseconds
    keyframes/cameras/T.json            ARKit's camera of photo T: fx, fy, cx, cy, width, height
                                        (pixels of the photo), blur_score, and t_00 ... t_23: rows 0-2 of
                                        the 4x4 camera-to-world (t_ij = row i, column j)
    keyframes/corrected_images/T.jpg    the photos undistorted during Polycam's pose optimisation
    keyframes/corrected_cameras/T.json  their globally optimised (loop-closed) cameras, same fields
    keyframes/depth/T.png               LiDAR depth, 16-bit millimetres, at a smaller size of the photo's
                                        aspect ratio (256 x 192)
    keyframes/confidence/T.png          its confidence, 0 low / 127 medium / 255 high
    raw.glb, mesh_info.json, polycam.mp4, thumbnail.jpg   the app's own mesh and previews (not read)

Poses follow ARKit's gravity-aligned convention, world +Y up, camera axes OpenGL's (the README; and
nerfstudio's process_data/polycam_utils.py keeps the camera axes and only permutes the world's), so
they are mapped by `arkit.arkit_to_engine`. The corrected photos and cameras are used when the export
has them (Polycam optimises sessions of up to about 700 frames, 1400 with Loop Closure); otherwise
the raw photos, which have slight lens distortion no file describes, with ARKit's unoptimised poses
and a warning. Depth was measured for the raw photo, so beside an undistorted one it is off by that
slight distortion near the borders.

Confidence maps are attached with `confidence_high=255`, so they read back as ARKit's 0 / 1 / 2.

A photo without its camera JSON, or whose JSON is unusable, is skipped with a warning naming it; a
photo whose depth map is missing or unreadable is used without depth, with a warning.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn
from .arkit import arkit_to_engine, finish_phone_capture, frames_of_photos, read_json_object
from .checks import SkippedPhotos, inspect_images
from .geometry import PoseRepairs, pinhole
from .images import list_images
from .model import Capture, SensorDepth
from .naming import name_list
from .options import LoadOptions

APP = "Polycam"
_KEYFRAME_FOLDERS = ("images", "corrected_images", "cameras", "corrected_cameras")
_TRANSFORM_KEYS = tuple(f"t_{row}{column}" for row in range(3) for column in range(4))
_ADVICE = ("export the capture from Polycam again with \"Raw Data\" (Settings > Developer mode must be on, for a "
           "LiDAR or Room capture)")


def is_polycam_folder(path: Path) -> bool:
    """A raw-data export: a `keyframes/` folder holding any of Polycam's images/cameras folders."""
    keyframes = path / "keyframes"
    return keyframes.is_dir() and any((keyframes / name).is_dir() for name in _KEYFRAME_FOLDERS)


def _camera_record(path: Path) -> tuple[np.ndarray, np.ndarray, tuple[int, int]]:
    """(ARKit camera-to-world (4, 4), K (3, 3), (width, height) the camera states) from one camera
    JSON; ValueError saying what is wrong."""
    data = read_json_object(path)
    missing = [key for key in ("fx", "fy", "cx", "cy", "width", "height", *_TRANSFORM_KEYS) if key not in data]
    if missing:
        raise ValueError(f"no {', '.join(missing[:4])}{' ...' if len(missing) > 4 else ''}")
    try:
        rows = np.array([data[key] for key in _TRANSFORM_KEYS], dtype=np.float64).reshape(3, 4)
        fx, fy, cx, cy = (float(data[key]) for key in ("fx", "fy", "cx", "cy"))
        width, height = int(data["width"]), int(data["height"])
    except (TypeError, ValueError) as error:
        raise ValueError(f"intrinsics or transform are not numbers ({error})") from error
    if not (np.isfinite([fx, fy, cx, cy]).all() and fx > 0 and fy > 0 and width > 0 and height > 0):
        raise ValueError(f"intrinsics without a positive focal length and size (fx {fx:g}, fy {fy:g}, "
                         f"{width} x {height})")
    transform = np.vstack([rows, [0.0, 0.0, 0.0, 1.0]])  # the files omit the last row, always 0 0 0 1
    return transform, pinhole(fx, fy, cx, cy), (width, height)


def _sources(keyframes: Path, warnings: list[str]) -> tuple[Path, Path]:
    """(photo folder, camera folder): the corrected pair when the export has both, else the raw pair
    (with a warning); CaptureError naming what is missing when neither is there."""
    corrected_images, corrected_cameras = keyframes / "corrected_images", keyframes / "corrected_cameras"
    if corrected_images.is_dir() and corrected_cameras.is_dir() and list_images(corrected_images):
        return corrected_images, corrected_cameras
    images, cameras = keyframes / "images", keyframes / "cameras"
    if not images.is_dir() or not list_images(images):
        raise CaptureError(f"{keyframes} holds no photos (neither corrected_images/ nor images/ has any): {_ADVICE}.")
    if not cameras.is_dir():
        raise CaptureError(f"{cameras} is missing: it holds the camera pose and intrinsics of every photo, without "
                           f"which the export cannot be used; {_ADVICE}.")
    warnings.append(f"{keyframes} has no corrected_images/ and corrected_cameras/ (Polycam optimises the poses of "
                    "captures up to about 700 frames, 1400 with Loop Closure): using the raw images/, which have "
                    "slight lens distortion, with ARKit's unoptimised poses")
    return images, cameras


def load_polycam(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                 cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "polycam") of the Polycam raw-data export folder `path`."""
    keyframes = path / "keyframes"
    warnings: list[str] = []
    images, cameras = _sources(keyframes, warnings)
    photos = list_images(images)
    repairs = PoseRepairs()
    no_json, bad_json, no_depth = [], [], []
    entries: list[tuple[Path, np.ndarray, np.ndarray, tuple[int, int], Optional[SensorDepth]]] = []
    for photo in photos:
        record = cameras / f"{photo.stem}.json"
        if not record.is_file():
            no_json.append(photo.name)
            continue
        try:
            transform, K, stated_size = _camera_record(record)
            pose = arkit_to_engine(repairs.make_rigid(transform, f"{cameras.name}/{record.name}"))
        except ValueError as error:
            bad_json.append(f"{cameras.name}/{record.name} ({error})")
            continue
        depth = keyframes / "depth" / f"{photo.stem}.png"
        sensor = None
        if depth.is_file():
            confidence = keyframes / "confidence" / f"{photo.stem}.png"
            sensor = SensorDepth(depth, "png_mm", confidence if confidence.is_file() else None, confidence_high=255)
        else:
            no_depth.append(photo.name)
        entries.append((photo, pose, K, stated_size, sensor))

    if no_json:
        warnings.append(f"{len(no_json)} photo(s) have no camera file in {cameras.name}/, skipped: "
                        f"{name_list(no_json)}")
    if bad_json:
        warnings.append(f"{len(bad_json)} camera file(s) are unusable, their photos skipped: {name_list(bad_json)}")
    if repairs.warning():
        warnings.append(f"{cameras}: {repairs.warning()}")
    with_depth = len(entries) - len(no_depth)
    if no_depth and with_depth:  # an export without any depth is no problem
        warnings.append(f"{len(no_depth)} photo(s) have no keyframes/depth/T.png, used without depth: "
                        f"{name_list(no_depth)}")
    if not entries:
        raise CaptureError(f"no photo of {images} has a usable camera in {cameras} ({'; '.join(warnings)}): {_ADVICE}.")

    skipped = SkippedPhotos()
    infos = inspect_images([photo for photo, _, _, _, _ in entries], skipped, verify=options.verify_images,
                           progress=progress, cancel=cancel)
    frames, usable_infos = frames_of_photos(entries, infos, skipped, lambda photo: f"{cameras.name}/{photo.stem}.json",
                                            warnings)
    capture = finish_phone_capture(path, "polycam", APP, frames, usable_infos, images, options, warnings, skipped)
    if images.name == "corrected_images":
        capture.notes.append(f"Polycam's undistorted photos and optimised poses used ({images.name}/, "
                             f"{cameras.name}/)")
    return capture
