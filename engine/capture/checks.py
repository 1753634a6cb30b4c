"""Checks every loader applies to its frames before handing out a Capture.

- Every photo is opened and (by default) decoded at 1/8 scale, so a corrupt file fails here, at
  load time, with its name, and not an hour later in the middle of a reconstruction.
- Byte-identical photos (a file copied twice) are dropped with a warning naming both: a user who
  copied a folder twice expects the capture to still load, and identical views add nothing.
- All photos must have one resolution (the network batches views of one size; COLMAP and
  transforms.json intrinsics are per camera): otherwise an error names one file of each size.
- At least MIN_FRAMES = 2 frames must remain. That is only the load-time minimum (two views are the
  least that pose estimation can relate); a useful room reconstruction needs dozens of overlapping
  photos, which the poses and reconstruction stages check with their own messages.
"""

from __future__ import annotations

from pathlib import Path
from typing import Optional

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn, check, report
from .images import ImageInfo, read_image_info
from .model import Capture, Frame
from .naming import name_list

MIN_FRAMES = 2


def inspect_images(paths: list[Path], verify: bool = True, progress: Optional[ProgressFn] = None,
                   cancel: Optional[CancelToken] = None) -> list[ImageInfo]:
    """`read_image_info` for each path (same order); raises CaptureError at the first bad file."""
    infos = []
    for i, path in enumerate(paths):
        check(cancel)
        report(progress, "checking photos", i, len(paths))
        infos.append(read_image_info(path, verify=verify))
    report(progress, "checking photos", len(paths), len(paths))
    return infos


def drop_duplicates(frames: list[Frame], infos: list[ImageInfo]) -> tuple[list[Frame], list[ImageInfo], list[str]]:
    """Keeps the first of each set of byte-identical photos; returns kept frames, infos and warnings."""
    first_with_digest: dict[str, ImageInfo] = {}
    kept_frames, kept_infos, dropped = [], [], []
    for frame, info in zip(frames, infos):
        original = first_with_digest.get(info.digest)
        if original is None:
            first_with_digest[info.digest] = info
            kept_frames.append(frame)
            kept_infos.append(info)
        else:
            dropped.append(f"{info.path.name} (same as {original.path.name})")
    warnings = []
    if dropped:
        warnings.append(f"{len(dropped)} duplicate photo(s) dropped, byte-identical to an earlier one: "
                        f"{name_list(dropped)}")
    return kept_frames, kept_infos, warnings


def require_one_resolution(infos: list[ImageInfo], where: Path) -> None:
    """CaptureError naming one file of each size when the photos' (oriented) sizes differ."""
    example_of_size: dict[tuple[int, int], ImageInfo] = {}
    for info in infos:
        example_of_size.setdefault(info.size, info)
    if len(example_of_size) > 1:
        examples = [f"{info.path.name} is {w} x {h}" for (w, h), info in example_of_size.items()]
        raise CaptureError(f"the photos in {where} have different resolutions: {name_list(examples, 5)}. "
                           "Use photos from one camera at one resolution: resize them to one size or "
                           "remove the odd ones.")


def require_frames(frames: list[Frame], where: Path, what: str = "photo", dropped: str = "") -> None:
    """CaptureError unless at least MIN_FRAMES frames remain; `dropped` says why others went."""
    if len(frames) >= MIN_FRAMES:
        return
    found = f"only 1 {what} ({frames[0].name})" if frames else f"no {what}s"
    raise CaptureError(f"{where} has {found}{dropped}: at least {MIN_FRAMES} are needed to load a capture, and a "
                       "reconstruction needs many more (a few dozen overlapping photos of the room). "
                       "Add more photos.")


def finish_capture(root: Path, format: str, frames: list[Frame], infos: list[ImageInfo], where: Path,
                   metric: bool, warnings: list[str], what: str = "photo") -> Capture:
    """The common tail of every loader: drop duplicates, require one resolution and >= 2 frames."""
    count = len(frames)
    frames, infos, duplicate_warnings = drop_duplicates(frames, infos)
    require_one_resolution(infos, where)
    dropped = f" after dropping {count - len(frames)} byte-identical duplicate(s)" if count > len(frames) else ""
    require_frames(frames, where, what, dropped)
    return Capture(root=root, format=format, frames=frames, metric=metric,
                   warnings=list(warnings) + duplicate_warnings)
