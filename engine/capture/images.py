"""Photo files: finding them, checking them cheaply at load time, decoding them, and decoding them
at the size a reconstruction step works at (`resized_size`, `load_resized`).

Sizes are read with Pillow (header + EXIF only) and the pixels are decoded with OpenCV; both apply
the EXIF orientation the same way (checked by tests for all 8 orientations), so `Frame.width/height`
always match what `load_image` returns.
"""

from __future__ import annotations

import hashlib
import io
from dataclasses import dataclass
from pathlib import Path
from typing import TYPE_CHECKING, Optional

import numpy as np

from ..errors import CaptureError
from . import exif as exif_tags
from .naming import natural_key

if TYPE_CHECKING:
    from .model import Frame

IMAGE_SUFFIXES = (".jpg", ".jpeg", ".png")
# The 2D CNN's FPN upsamples its stride-16 map onto the stride-8 and stride-4 maps exactly only when
# both image sides are multiples of 16.
SIZE_MULTIPLE = 16
# Pillow format names that OpenCV decodes too ("MPO" is the multi-picture JPEG some cameras write).
_DECODABLE_FORMATS = ("JPEG", "MPO", "PNG")


def is_image_file(path: Path) -> bool:
    """A JPEG/PNG by suffix (any case); hidden files such as macOS `._IMG_1.jpg` do not count."""
    return path.suffix.lower() in IMAGE_SUFFIXES and not path.name.startswith(".") and path.is_file()


def list_images(folder: Path) -> list[Path]:
    """The photos directly inside `folder` (not recursive), in natural order (frame2 < frame10)."""
    return sorted((p for p in folder.iterdir() if is_image_file(p)), key=lambda p: natural_key(p.name))


@dataclass(frozen=True)
class ImageInfo:
    """What the loaders need to know about one photo without keeping its pixels."""

    path: Path
    width: int  # after EXIF orientation
    height: int  # after EXIF orientation
    orientation: int  # EXIF orientation 1..8 (1 = none)
    focal_px: Optional[float]  # focal length in pixels from EXIF, None when unknown
    digest: str  # content hash: byte-identical files have equal digests

    @property
    def size(self) -> tuple[int, int]:
        return (self.width, self.height)


class UnusableImage(CaptureError):
    """A photo that cannot be used (unreadable, empty, corrupt, truncated, not a JPEG/PNG).

    `reason` is the short form ("truncated or corrupt (...)") that a loader puts in its warning when
    it skips the photo and goes on; str(error) is the full message naming the path and what to do.
    """

    def __init__(self, path: Path, reason: str, advice: str) -> None:
        super().__init__(f"image {path} is {reason}: {advice}.")
        self.path = Path(path)
        self.reason = reason
        self.advice = advice


def read_image_info(path: Path, verify: bool = True) -> ImageInfo:
    """Size, orientation, EXIF focal length and content hash of one photo.

    With `verify`, the pixels are decoded too, at 1/8 scale through libjpeg's DCT scaling
    (about 5 ms for a 2-megapixel JPEG), because a truncated JPEG has a valid header: Pillow raises
    "image file is truncated" on it (checked with real photos cut at 50 % and 99.9 % of their bytes,
    and with only the end-of-image marker missing). Raises UnusableImage naming the file when it is
    unreadable, empty, not a JPEG/PNG, or corrupt.
    """
    try:
        data = path.read_bytes()
    except OSError as error:
        raise UnusableImage(path, f"unreadable ({error.strerror or error})",
                            "check that the file exists and is readable") from error
    if not data:
        raise UnusableImage(path, "an empty file (0 bytes)", "re-copy it, or remove it from the capture")
    digest = hashlib.blake2b(data, digest_size=16).hexdigest()
    from PIL import Image  # defers PIL: the extension registers in a Blender without Pillow

    try:
        with Image.open(io.BytesIO(data)) as image:
            if image.format not in _DECODABLE_FORMATS:
                raise UnusableImage(path, f"a {image.format} file, not a JPEG or PNG",
                                    "convert it to JPEG or PNG, or remove it from the capture")
            stored_width, stored_height = image.size
            exif = image.getexif()
            if verify:
                image.draft(image.mode, (max(1, stored_width // 8), max(1, stored_height // 8)))
                image.load()
    except UnusableImage:
        raise
    except Exception as error:  # Pillow raises OSError, SyntaxError, ValueError... on broken files
        raise UnusableImage(path, f"corrupt, truncated or not an image ({error})",
                            "re-export or re-copy it, or remove it from the capture") from error
    if stored_width < 1 or stored_height < 1:
        raise UnusableImage(path, f"without pixels ({stored_width} x {stored_height})", "remove it")
    orientation = exif_tags.orientation(exif)
    width, height = stored_width, stored_height
    if orientation in exif_tags.TRANSPOSING_ORIENTATIONS:
        width, height = height, width
    focal_px = exif_tags.focal_length_pixels(exif, stored_width, stored_height)
    return ImageInfo(path=path, width=width, height=height, orientation=orientation, focal_px=focal_px,
                     digest=digest)


def load_image(path: Path | str) -> np.ndarray:
    """The photo as uint8 RGB, shape (H, W, 3), EXIF orientation applied.

    Decodes through `cv2.imdecode` on the file's bytes rather than `cv2.imread`, because imread
    cannot open non-ASCII paths on Windows. IMREAD_COLOR applies EXIF orientation and turns
    grey, palette, alpha and 16-bit images into 8-bit 3-channel.
    """
    path = Path(path)
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as error:
        raise CaptureError(f"cannot read image {path}: {error.strerror or error}. Check that the file exists "
                           "and is readable.") from error
    import cv2  # defers cv2 (OpenCV) off the light paths
    bgr = cv2.imdecode(data, cv2.IMREAD_COLOR) if data.size else None
    if bgr is None:
        raise CaptureError(f"image {path} cannot be decoded (corrupt or not a JPEG/PNG): re-export it or "
                           "remove it from the capture.")
    return cv2.cvtColor(bgr, cv2.COLOR_BGR2RGB)


def load_depth(path: Path | str) -> np.ndarray:
    """A ScanNet-style depth map (16-bit PNG, millimetres) as float32 metres (H, W); 0 = no depth."""
    path = Path(path)
    try:
        data = np.fromfile(str(path), dtype=np.uint8)
    except OSError as error:
        raise CaptureError(f"cannot read depth map {path}: {error.strerror or error}") from error
    import cv2  # defers cv2 (OpenCV) off the light paths
    depth = cv2.imdecode(data, cv2.IMREAD_UNCHANGED) if data.size else None
    if depth is None or depth.ndim != 2:
        raise CaptureError(f"depth map {path} is not a single-channel 16-bit PNG in millimetres: re-export it "
                           "or remove it from the capture's depth/ folder.")
    return depth.astype(np.float32) / 1000.0


def intrinsics_from_focal(focal_px: float, width: int, height: int) -> np.ndarray:
    """Pinhole K (3, 3) float64 with the principal point at the image centre.

    The centre is (W/2, H/2): pixel (0, 0) covers [0, 1) x [0, 1), the convention of COLMAP and of
    the Blender camera conversion (shift = (W/2 - cx) / max(W, H)).
    """
    return np.array([[focal_px, 0.0, width / 2.0], [0.0, focal_px, height / 2.0], [0.0, 0.0, 1.0]])


def resized_size(width: int, height: int, long_side: int, multiple: int = SIZE_MULTIPLE) -> tuple[int, int]:
    """(width, height) with the long side near `long_side`, both multiples of `multiple`.

    Rounding to the multiple makes the two axes scale by slightly different factors, so callers
    scale K per axis (`engine.geometry.cameras.scale_intrinsics`).
    """
    scale = long_side / max(width, height)
    w = max(multiple, int(round(width * scale / multiple)) * multiple)
    h = max(multiple, int(round(height * scale / multiple)) * multiple)
    return w, h


def load_resized(frame: "Frame", size: tuple[int, int]) -> np.ndarray:
    """The frame's image as uint8 (h, w, 3) RGB at `size` = (w, h).

    Downscaling uses area averaging: it is the right low-pass filter before sampling colours at
    vertex spacing, and for the CNN it matches how a camera with fewer pixels would see the scene.
    """
    image = load_image(frame.image_path)
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    import cv2  # defers cv2 (OpenCV) off the light paths
    shrinking = size[0] < image.shape[1]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
