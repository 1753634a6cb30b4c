"""Loader for the ScanNet export layout (format "scannet"), also written by our synthetic renderer.

    color/<stem>.jpg|png        photos (natural order: 0, 1, ..., 10)
    pose/<stem>.txt             4x4 camera-to-world, OpenCV camera axes, metres, world Z up
    intrinsic/intrinsic_color.txt   4x4 (or 3x3) K of the colour images
    depth/<stem>.png            optional 16-bit depth in millimetres -> Frame.depth_path

`metric` is True (ScanNet poses are in metres) unless the `metric=` option overrides it. Frames
without a pose file, or whose matrix is not finite (ScanNet writes -inf where tracking was lost) or
not a rotation, are skipped with one warning naming them; rotations orthonormal only to a few digits
are made exact (`geometry.PoseRepairs`). The depth images have their own
intrinsics (`intrinsic/intrinsic_depth.txt`), which this loader does not read.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

import numpy as np

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn
from .checks import SkippedPhotos, finish_capture, inspect_images
from .geometry import PoseRepairs, parse_pose
from .images import list_images
from .model import Capture, Frame
from .naming import name_list
from .options import LoadOptions


def is_scannet_folder(path: Path) -> bool:
    return (path / "color").is_dir() and (path / "pose").is_dir()


def _read_matrix(path: Path) -> np.ndarray:
    """Whitespace-separated numbers of a text matrix; ValueError when it is not numeric."""
    rows = [line.split() for line in path.read_text(encoding="utf-8", errors="replace").splitlines() if line.strip()]
    return np.array([[float(v) for v in row] for row in rows], dtype=np.float64)


def read_color_intrinsics(path: Path) -> np.ndarray:
    """K (3, 3) from ScanNet's intrinsic_color.txt (4x4 or 3x3)."""
    file = path / "intrinsic" / "intrinsic_color.txt"
    if not file.is_file():
        raise CaptureError(f"{file} is missing: a ScanNet export needs the colour camera's intrinsics there "
                           "(4x4 matrix, as written by ScanNet's SensReader).")
    try:
        matrix = _read_matrix(file)
    except ValueError as error:
        raise CaptureError(f"{file} is not a matrix of numbers ({error}): re-export it.") from error
    if matrix.shape not in ((3, 3), (4, 4)) or not np.all(np.isfinite(matrix[:3, :3])) or matrix[0, 0] <= 0:
        raise CaptureError(f"{file} should hold a 4x4 or 3x3 intrinsic matrix with a positive focal length, "
                           f"found shape {matrix.shape}: re-export it.")
    return matrix[:3, :3].copy()


def load_scannet(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                 cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "scannet") of the ScanNet-layout folder `path`."""
    K = read_color_intrinsics(path)
    photos = list_images(path / "color")
    if not photos:
        raise CaptureError(f"{path / 'color'} holds no JPEG or PNG photos: this ScanNet export is empty.")
    no_pose, bad_pose, entries = [], [], []
    repairs = PoseRepairs()
    for photo in photos:
        pose_file = path / "pose" / f"{photo.stem}.txt"
        if not pose_file.is_file():
            no_pose.append(photo.name)
            continue
        try:
            pose = repairs.make_rigid(parse_pose(_read_matrix(pose_file)), pose_file.name)
        except (ValueError, OSError) as error:
            bad_pose.append(f"{pose_file.name} ({error})")
            continue
        depth = path / "depth" / f"{photo.stem}.png"
        entries.append((photo, pose, depth if depth.is_file() else None))

    warnings = []
    if no_pose:
        warnings.append(f"{len(no_pose)} photo(s) in {path / 'color'} have no pose file in {path / 'pose'}, skipped: "
                        f"{name_list(no_pose)}")
    if bad_pose:
        warnings.append(f"{len(bad_pose)} pose file(s) in {path / 'pose'} are unusable, frames skipped: "
                        f"{name_list(bad_pose)}")
    if repairs.warning():
        warnings.append(f"{path / 'pose'}: {repairs.warning()}")
    if not entries:
        raise CaptureError(f"no frame of {path} has a usable pose ({'; '.join(warnings)}): check the files in "
                           f"{path / 'pose'}.")

    skipped = SkippedPhotos()
    infos = inspect_images([p for p, _, _ in entries], skipped, verify=options.verify_images, progress=progress,
                           cancel=cancel)
    usable = [(entry, info) for entry, info in zip(entries, infos) if info is not None]
    frames = [Frame(image_path=photo, width=info.width, height=info.height, K=K.copy(), pose=pose, depth_path=depth)
              for (photo, pose, depth), info in usable]
    metric = True if options.metric is None else options.metric
    return finish_capture(path, "scannet", frames, [info for _, info in usable], path / "color", metric, warnings,
                          skipped, what="posed photo")
