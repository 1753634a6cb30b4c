"""`load_capture`: one entry point for every capture layout."""

from __future__ import annotations

from pathlib import Path
from typing import Any, Callable, Optional

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn
from .archive import is_archive, unpacked_archive
from .arkitscenes import load_arkitscenes
from .colmap import load_colmap
from .detect import FORMATS, detect_format
from .folder import load_photo_folder
from .model import Capture
from .options import LoadOptions
from .polycam import load_polycam
from .record3d import load_record3d
from .scannet import load_scannet
from .sensor_depth import sensor_points
from .scanner_app import load_scanner_app
from .stray_scanner import load_stray_scanner
from .transforms_json import load_transforms
from .video import load_video

_LOADERS: dict[str, Callable[..., Capture]] = {
    "images": load_photo_folder,
    "colmap": load_colmap,
    "transforms": load_transforms,
    "scannet": load_scannet,
    "video": load_video,
    "3dscannerapp": load_scanner_app,
    "strayscanner": load_stray_scanner,
    "record3d": load_record3d,
    "polycam": load_polycam,
    "arkitscenes": load_arkitscenes,
}


def load_capture(path: Path | str, *, format: Optional[str] = None, progress: Optional[ProgressFn] = None,
                 cancel: Optional[CancelToken] = None, **options: Any) -> Capture:
    """Load the capture at `path`, detecting its layout (see `detect.py`) unless `format` is given.

    A zip (.zip, Record3D's .r3d) is unpacked into the cache first and its folder loaded.
    `options` are the fields of `LoadOptions`: fps, blur_fraction (video), metric (override),
    undistort, cache_dir, images_dir (COLMAP), verify_images. Returns a Capture whose `root` is
    `path` as given (made absolute): a folder, or the video / transforms.json file. Raises
    CaptureError with a message naming the file at fault and what to do; progress is reported
    for the slow steps (checking photos, extracting video frames, undistorting).
    """
    path = Path(path).expanduser().absolute()
    load_options = LoadOptions.from_kwargs(options)
    archive = path if is_archive(path) else None
    if archive is not None:  # a zipped export: its unpacked folder, detected and loaded as any folder
        path = unpacked_archive(archive, load_options.cache_dir, progress, cancel)
    if format is None:
        format = detect_format(path)
    elif format not in FORMATS:
        raise CaptureError(f"unknown capture format {format!r}: choose one of {', '.join(FORMATS)}.")
    elif not path.exists():
        detect_format(path)  # raises the "does not exist" message
    capture = _LOADERS[format](path, load_options, progress=progress, cancel=cancel)
    if capture.points is None and capture.frames_with_sensor_depth:
        # A phone's depth is the capture's point cloud (shown on import; tight stereo depth ranges).
        capture = capture.with_points(*sensor_points(capture.frames))
    if archive is not None:
        capture.notes.append(f"{archive.name} unpacked into {path}")
    return capture
