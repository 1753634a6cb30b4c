"""Which on-disk layout a capture path is, decided from file names only (nothing is parsed).

Order of precedence for a folder, first match wins:
0. a phone scanning app's export (`PHONE_EXPORTS`: 3D Scanner App "All Data", ...)
1. `transforms.json` in it            -> "transforms" (instant-ngp / nerfstudio)
2. `color/` and `pose/` sub-folders   -> "scannet"
3. a COLMAP model (`sparse/<n>/`, `sparse/`, `colmap/sparse/<n>/` or the folder itself) -> "colmap"
4. JPEG/PNG photos in it or in `images/` -> "images"
A file: a video (.mp4 .mov .avi .m4v .mkv, any case) -> "video"; a .json file -> "transforms"; a zip
(.zip, Record3D's .r3d) is unpacked by `load_capture` first and its folder detected (`archive.py`).
A folder that has both transforms.json and a COLMAP model (nerfstudio's output) loads the former;
pass `format="colmap"` to choose the other.
"""

from __future__ import annotations

from pathlib import Path
from typing import Callable

from ..errors import CaptureError
from .archive import ARCHIVE_SUFFIXES
from .arkitscenes import is_arkitscenes_folder
from .colmap import find_model_folders
from .folder import photo_folder
from .images import IMAGE_SUFFIXES
from .naming import name_list
from .polycam import is_polycam_folder
from .record3d import is_record3d_folder
from .scannet import is_scannet_folder
from .scanner_app import is_scanner_app_folder
from .stray_scanner import is_stray_scanner_folder
from .video import VIDEO_SUFFIXES, is_video_file

# Phone scanning apps' exports and ARKitScenes' raw iPad captures (ARKit poses, often LiDAR depth):
# format name -> folder test.
PHONE_EXPORTS: dict[str, Callable[[Path], bool]] = {
    "3dscannerapp": is_scanner_app_folder,
    "strayscanner": is_stray_scanner_folder,
    "record3d": is_record3d_folder,
    "polycam": is_polycam_folder,
    "arkitscenes": is_arkitscenes_folder,
}
FORMATS = ("images", "colmap", "transforms", "scannet", "video", *PHONE_EXPORTS)
_WHAT_IS_ACCEPTED = ("a folder of JPEG/PNG photos (or with an images/ sub-folder), a COLMAP project (sparse/ + "
                     "images/), a folder with transforms.json, a ScanNet export (color/ + pose/), a video file, or "
                     "a phone app's export (3D Scanner App, Stray Scanner, Record3D, Polycam: the folder or its zip) or an "
                     "ARKitScenes video folder")


def detect_format(path: Path) -> str:
    """One of FORMATS for `path`; CaptureError saying what was expected when it is none of them."""
    if not path.exists():
        raise CaptureError(f"capture not found: {path} does not exist. Choose {_WHAT_IS_ACCEPTED}.")
    if path.is_file():
        suffix = path.suffix.lower()
        if is_video_file(path):
            return "video"
        if suffix == ".json":
            return "transforms"
        if suffix in ARCHIVE_SUFFIXES:
            raise CaptureError(f"{path} is an archive: load_capture unpacks it first (engine.capture.archive).")
        if suffix in IMAGE_SUFFIXES:
            raise CaptureError(f"{path} is a single photo: choose the folder holding all the photos of the room.")
        raise CaptureError(f"{path} is not a capture (a {suffix or 'suffix-less'} file): choose {_WHAT_IS_ACCEPTED}.")
    try:
        entries = [p for p in path.iterdir() if not p.name.startswith(".")]
    except OSError as error:
        raise CaptureError(f"cannot list folder {path}: {error.strerror or error}.") from error
    for name, is_export in PHONE_EXPORTS.items():
        if is_export(path):
            return name
    if (path / "transforms.json").is_file():
        return "transforms"
    if is_scannet_folder(path):
        return "scannet"
    if find_model_folders(path):
        return "colmap"
    if photo_folder(path) is not None:
        return "images"
    if not entries:
        raise CaptureError(f"capture folder {path} is empty: put the photos of the room (JPEG or PNG) in it, or "
                           "choose another folder.")
    videos = [p.name for p in entries if is_video_file(p)]
    if videos:
        raise CaptureError(f"no photos in {path}, but it holds video file(s) {name_list(videos, 5)}: choose the "
                           "video file itself to extract frames from it.")
    examples = name_list(sorted(p.name for p in entries)[:5], 5)
    raise CaptureError(f"no photos found in {path} (it holds {len(entries)} other item(s), e.g. {examples}). Choose "
                       f"{_WHAT_IS_ACCEPTED}; photos must end in .jpg, .jpeg or .png and videos in "
                       f"{', '.join(VIDEO_SUFFIXES)}.")
