"""Loader for a plain folder of photos (format "images"): no poses, K from EXIF when it can be.

Accepted layouts: JPEG/PNG files (any suffix case) directly in the folder, or in its `images/`
sub-folder. Frames are in natural file-name order. K per frame is built from the EXIF focal length
(see `exif.py`) with the principal point at the image centre, or None when EXIF does not give it:
pose estimation then estimates the focal length.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn
from .checks import SkippedPhotos, finish_capture, inspect_images
from .images import intrinsics_from_focal, list_images
from .model import Capture, Frame
from .options import LoadOptions


def photo_folder(folder: Path) -> Optional[Path]:
    """The folder holding the photos of a plain capture: `folder` itself or `folder/images`."""
    if list_images(folder):
        return folder
    images = folder / "images"
    if images.is_dir() and list_images(images):
        return images
    return None


def capture_from_photos(paths: list[Path], root: Path, format: str, where: Path, options: LoadOptions,
                        warnings: Optional[list[str]] = None, progress: Optional[ProgressFn] = None,
                        cancel: Optional[CancelToken] = None) -> Capture:
    """An unposed Capture of `paths` (ordered); `where` is the folder named in error messages."""
    skipped = SkippedPhotos()
    infos = [info for info in inspect_images(paths, skipped, verify=options.verify_images, progress=progress,
                                             cancel=cancel) if info is not None]
    frames = [Frame(image_path=info.path, width=info.width, height=info.height,
                    K=None if info.focal_px is None else intrinsics_from_focal(info.focal_px, info.width, info.height))
              for info in infos]
    warnings = list(warnings or [])
    with_focal = sum(info.focal_px is not None for info in infos)
    if 0 < with_focal < len(infos):
        warnings.append(f"EXIF gives the focal length for only {with_focal} of {len(infos)} photos; the "
                        "others' intrinsics will be estimated")
    if options.metric:
        warnings.append("metric=True ignored: this capture has no poses, so its scale comes from the poses stage")
    return finish_capture(root, format, frames, infos, where, metric=False, warnings=warnings, skipped=skipped)


def load_photo_folder(path: Path, options: LoadOptions, progress: Optional[ProgressFn] = None,
                      cancel: Optional[CancelToken] = None) -> Capture:
    """Capture (format "images") of the photos in `path` or `path/images`."""
    folder = photo_folder(path)
    if folder is None:
        raise CaptureError(f"no JPEG or PNG photos in {path} or {path / 'images'}: add the photos there.")
    return capture_from_photos(list_images(folder), root=path, format="images", where=folder, options=options,
                               progress=progress, cancel=cancel)
