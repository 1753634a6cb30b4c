"""Checks every loader applies to its frames before handing out a Capture.

Skip, warn, go on: a capture of 200 photos with one bad file loads without it and says which.
- Every photo is opened and (by default) decoded at 1/8 scale, so a corrupt, truncated, empty or
  unreadable file is found here, at load time, and not an hour later in the middle of a
  reconstruction. It is skipped; one warning names every skipped photo and why (`SkippedPhotos`).
- A photo whose size does not fit its capture's intrinsics (another aspect ratio than the camera the
  file states) is skipped the same way by the loaders that have intrinsics.
- Byte-identical photos (a file copied twice) are dropped with a warning naming both: a user who
  copied a folder twice expects the capture to still load, and identical views add nothing.
- All photos must have one resolution (the network batches views of one size). Photos of another
  size are skipped when the most common size holds at least ODD_SIZE_MAJORITY of the photos (a few
  stray screenshots or edited copies); otherwise (two cameras) an error names one file of each size.
- At least MIN_FRAMES = 2 frames must remain, else the error says how many photos were skipped and
  why. That is only the load-time minimum (two views are the least that pose estimation can relate);
  a useful room reconstruction needs dozens of overlapping photos, which the poses and
  reconstruction stages check with their own messages.
"""

from __future__ import annotations

from collections import Counter
from dataclasses import dataclass, field
from pathlib import Path
from typing import Optional

from ..errors import CaptureError
from ..jobs import CancelToken, ProgressFn, check, report
from .images import ImageInfo, UnusableImage, read_image_info
from .model import Capture, Frame
from .naming import name_list

MIN_FRAMES = 2
# Photos of another size than the most common one are skipped only when that size holds at least
# this share: 3 screenshots among 200 photos are strays, 80 photos of 200 are a second camera.
ODD_SIZE_MAJORITY = 0.75


@dataclass
class SkippedPhotos:
    """The photos a loader left out of the capture, each with a short reason and advice."""

    entries: list[tuple[str, str, str]] = field(default_factory=list)  # (file name, reason, what to do)

    def add(self, error: UnusableImage) -> None:
        self.entries.append((error.path.name, error.reason, error.advice))

    def __len__(self) -> int:
        return len(self.entries)

    def _listed(self) -> str:
        return name_list([f"{name} ({reason})" for name, reason, _ in self.entries], limit=10)

    def warning(self) -> Optional[str]:
        """One warning naming every skipped photo and why, or None."""
        if not self.entries:
            return None
        return f"{len(self.entries)} photo(s) skipped, the capture goes on without them: {self._listed()}"

    def explanation(self) -> str:
        """" after skipping 3 unusable photo(s): a.jpg (...), ...", for the too-few-frames error; the
        advice of each kind of problem follows, so a capture whose every photo looks rotated still
        gets the hint about the EXIF orientation tag."""
        if not self.entries:
            return ""
        advice = list(dict.fromkeys(entry[2] for entry in self.entries))[:3]
        return (f" after skipping {len(self.entries)} unusable photo(s): {self._listed()} "
                f"(to use them: {'; '.join(advice)})")


def inspect_images(paths: list[Path], skipped: SkippedPhotos, verify: bool = True,
                   progress: Optional[ProgressFn] = None,
                   cancel: Optional[CancelToken] = None) -> list[Optional[ImageInfo]]:
    """`read_image_info` for each path (same order); None for a photo that cannot be used, which
    is recorded in `skipped` with its reason."""
    infos: list[Optional[ImageInfo]] = []
    for i, path in enumerate(paths):
        check(cancel)
        report(progress, "checking photos", i, len(paths))
        try:
            infos.append(read_image_info(path, verify=verify))
        except UnusableImage as error:
            skipped.add(error)
            infos.append(None)
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


def keep_one_resolution(frames: list[Frame], infos: list[ImageInfo], where: Path,
                        skipped: SkippedPhotos) -> tuple[list[Frame], list[ImageInfo]]:
    """The frames of the most common (oriented) size; the others are recorded in `skipped` when that
    size holds at least ODD_SIZE_MAJORITY of the photos, else CaptureError naming one file of each size."""
    counts = Counter(info.size for info in infos)
    if len(counts) <= 1:
        return frames, infos
    (width, height), count = counts.most_common(1)[0]
    if count < ODD_SIZE_MAJORITY * len(infos):
        example_of_size: dict[tuple[int, int], ImageInfo] = {}
        for info in infos:
            example_of_size.setdefault(info.size, info)
        examples = [f"{info.path.name} is {w} x {h}" for (w, h), info in example_of_size.items()]
        raise CaptureError(f"the photos in {where} have different resolutions: {name_list(examples, 5)}. "
                           "Use photos from one camera at one resolution: resize them to one size or "
                           "remove the odd ones.")
    kept_frames, kept_infos = [], []
    for frame, info in zip(frames, infos):
        if info.size == (width, height):
            kept_frames.append(frame)
            kept_infos.append(info)
        else:
            skipped.add(UnusableImage(info.path, f"{info.width} x {info.height}, while {count} of the {len(infos)} "
                                                 f"photos are {width} x {height}",
                                      "resize them to the size of the others"))
    return kept_frames, kept_infos


def require_frames(frames: list[Frame], where: Path, what: str = "photo", dropped: str = "") -> None:
    """CaptureError unless at least MIN_FRAMES frames remain; `dropped` says why others went."""
    if len(frames) >= MIN_FRAMES:
        return
    found = f"only 1 {what} ({frames[0].name})" if frames else f"no {what}s"
    raise CaptureError(f"{where} has {found}{dropped}: at least {MIN_FRAMES} are needed to load a capture, and a "
                       "reconstruction needs many more (a few dozen overlapping photos of the room). "
                       "Add more photos.")


def finish_capture(root: Path, format: str, frames: list[Frame], infos: list[ImageInfo], where: Path,
                   metric: bool, warnings: list[str], skipped: SkippedPhotos, what: str = "photo") -> Capture:
    """The common tail of every loader: drop duplicates, keep one resolution, require >= 2 frames,
    and warn about the photos `skipped` on the way."""
    count = len(frames)
    frames, infos, duplicate_warnings = drop_duplicates(frames, infos)
    duplicates = count - len(frames)
    frames, infos = keep_one_resolution(frames, infos, where, skipped)
    dropped = f" after dropping {duplicates} byte-identical duplicate(s)" if duplicates else ""
    dropped = skipped.explanation() + (" and" if skipped and dropped else "") + dropped
    require_frames(frames, where, what, dropped)
    skip_warning = [skipped.warning()] if skipped else []
    return Capture(root=root, format=format, frames=frames, metric=metric,
                   warnings=list(warnings) + skip_warning + duplicate_warnings,
                   skipped=[name for name, _, _ in skipped.entries])
