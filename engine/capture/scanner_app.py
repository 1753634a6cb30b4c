"""Loader for the 3D Scanner App's "All Data" export (format "3dscannerapp"), an iPhone/iPad app.

    frame_NNNNN.jpg     photos (a subset of the tracked frames: 146 of 436 in a typical export)
    frame_NNNNN.json    one per tracked frame: `cameraPoseARFrame` (16 numbers, row-major 4x4 ARKit
                        camera-to-world) and `intrinsics` (9 numbers, row-major 3x3, pixels of the photo)
    depth_NNNNN.png     LiDAR depth, 16-bit millimetres, at a smaller size of the photo's aspect ratio
    conf_NNNNN.png      its confidence (0 low, 1 medium, 2 high)
    info.json           the export's metadata (app version, title)

Poses are ARKit's: metric and gravity-aligned (`arkit.arkit_to_engine`). The frame JSONs also hold
GPS fields (latitude, longitude, altitude); they are never read, so no output can carry them.
A photo without its JSON, or whose JSON lacks a usable pose or intrinsics, is skipped with a warning
naming it; a photo whose depth map is missing or unreadable is used without depth, with a warning.
"""

from __future__ import annotations

import re
from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn
from .arkit import arkit_to_engine, finish_phone_capture, read_json_object
from .checks import SkippedPhotos, inspect_images
from .geometry import PoseRepairs
from .model import Capture, Frame, SensorDepth
from .naming import name_list, natural_key
from .options import LoadOptions

APP = "3D Scanner App"
_PHOTO = re.compile(r"^frame_(\d+)\.jpe?g$", re.IGNORECASE)


def is_scanner_app_folder(path: Path) -> bool:
    """An "All Data" export: info.json beside frame_NNNNN.json files."""
    return (path / "info.json").is_file() and any(path.glob("frame_*.json"))


def _frame_record(path: Path) -> tuple[np.ndarray, np.ndarray]:
    """(ARKit camera-to-world (4, 4), K (3, 3)) from one frame JSON; ValueError saying what is wrong."""
    data = read_json_object(path)
    pose, intrinsics = data.get("cameraPoseARFrame"), data.get("intrinsics")
    if not isinstance(pose, list) or len(pose) != 16:
        raise ValueError("no cameraPoseARFrame of 16 numbers")
    if not isinstance(intrinsics, list) or len(intrinsics) != 9:
        raise ValueError("no intrinsics of 9 numbers")
    try:
        transform = np.array(pose, dtype=np.float64).reshape(4, 4)
        K = np.array(intrinsics, dtype=np.float64).reshape(3, 3)
    except (TypeError, ValueError) as error:
        raise ValueError(f"pose or intrinsics are not numbers ({error})") from error
    if not np.all(np.isfinite(K)) or K[0, 0] <= 0 or K[1, 1] <= 0:
        raise ValueError(f"intrinsics without a positive focal length: {intrinsics}")
    return transform, K


def load_scanner_app(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                     cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "3dscannerapp") of the 3D Scanner App export folder `path`."""
    photos = sorted((p for p in path.iterdir() if _PHOTO.match(p.name)), key=lambda p: natural_key(p.name))
    if not photos:
        raise CaptureError(f"{path} looks like a 3D Scanner App export (info.json, frame_*.json) but holds no "
                           "frame_NNNNN.jpg photos: export it again with \"All Data\", which includes the photos.")
    repairs = PoseRepairs()
    no_json, bad_json, no_depth = [], [], []
    entries: list[tuple[Path, np.ndarray, np.ndarray, Optional[SensorDepth]]] = []
    for photo in photos:
        number = _PHOTO.match(photo.name).group(1)
        record = path / f"frame_{number}.json"
        if not record.is_file():
            no_json.append(photo.name)
            continue
        try:
            transform, K = _frame_record(record)
            pose = arkit_to_engine(repairs.make_rigid(transform, record.name))
        except ValueError as error:
            bad_json.append(f"{record.name} ({error})")
            continue
        depth = path / f"depth_{number}.png"
        confidence = path / f"conf_{number}.png"
        sensor = None
        if depth.is_file():
            sensor = SensorDepth(depth, "png_mm", confidence if confidence.is_file() else None)
        else:
            no_depth.append(photo.name)
        entries.append((photo, pose, K, sensor))

    warnings: list[str] = []
    if no_json:
        warnings.append(f"{len(no_json)} photo(s) have no frame_NNNNN.json with their pose, skipped: {name_list(no_json)}")
    if bad_json:
        warnings.append(f"{len(bad_json)} frame file(s) are unusable, their photos skipped: {name_list(bad_json)}")
    if repairs.warning():
        warnings.append(f"{path}: {repairs.warning()}")
    with_depth = len(entries) - len(no_depth)
    if no_depth and with_depth:  # an export without any depth (a non-LiDAR phone) is no problem
        warnings.append(f"{len(no_depth)} photo(s) have no depth_NNNNN.png, used without depth: {name_list(no_depth)}")
    if not entries:
        raise CaptureError(f"no photo of {path} has a usable pose ({'; '.join(warnings)}): export the capture "
                           "again from the 3D Scanner App with \"All Data\".")

    skipped = SkippedPhotos()
    infos = inspect_images([photo for photo, _, _, _ in entries], skipped, verify=options.verify_images,
                           progress=progress, cancel=cancel)
    frames = [Frame(image_path=photo, width=info.width, height=info.height, K=K, pose=pose, sensor_depth=sensor)
              for (photo, pose, K, sensor), info in zip(entries, infos) if info is not None]
    capture = finish_phone_capture(path, "3dscannerapp", APP, frames, [info for info in infos if info is not None], path,
                                   options, warnings, skipped)
    return capture
