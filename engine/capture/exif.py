"""What EXIF tells us about a photo: its display orientation and its focal length in pixels.

Only cheap, standard tags are used (no sensor-size database):
1. `FocalLengthIn35mmFilm` (phones and most cameras write it). The equivalent focal length keeps the
   *diagonal* field of view of a 36 x 24 mm frame (diagonal 43.27 mm), so
   f_px = f35 * diagonal_px / 43.27. On the Sceaux castle photos (KODAK Z612, f35 = 35 mm,
   2832 x 2128) this gives 2866 px against a calibrated 2906 px (-1.4 %); the other common reading,
   f35 / 36 mm * long side, would give 2753 px (-5.3 %).
2. `FocalLength` (mm) with `FocalPlaneXResolution` / `FocalPlaneResolutionUnit` (pixels per unit on
   the sensor, written by most interchangeable-lens cameras), rescaled when the stored image is
   smaller than `PixelXDimension` (the size the camera recorded).
Otherwise the focal length is unknown (None) and structure from motion estimates it.
"""

from __future__ import annotations

import math
from typing import TYPE_CHECKING, Optional

if TYPE_CHECKING:  # Pillow is imported only where EXIF is read, so registering needs no Pillow
    from PIL import Image

ORIENTATION_TAG = 0x0112
# Orientations 5..8 store the picture transposed: displayed width and height are swapped.
TRANSPOSING_ORIENTATIONS = (5, 6, 7, 8)

_FOCAL_LENGTH = 0x920A
_FOCAL_LENGTH_35MM = 0xA405
_FOCAL_PLANE_X_RESOLUTION = 0xA20E
_FOCAL_PLANE_RESOLUTION_UNIT = 0xA210
_PIXEL_X_DIMENSION = 0xA002
_FILM_DIAGONAL_MM = math.hypot(36.0, 24.0)
# FocalPlaneResolutionUnit: 2 = inch, 3 = cm, 4 = mm, 5 = micrometre (EXIF 2.3 and common practice).
_UNIT_MM = {2: 25.4, 3: 10.0, 4: 1.0, 5: 0.001}


def orientation(exif: Image.Exif) -> int:
    """EXIF orientation 1..8 (1 = stored as displayed); anything invalid counts as 1."""
    value = exif.get(ORIENTATION_TAG, 1)
    try:
        value = int(value)
    except (TypeError, ValueError):
        return 1
    return value if 1 <= value <= 8 else 1


def _exif_tag(exif: Image.Exif, tag: int) -> Optional[float]:
    """A numeric tag from the Exif sub-IFD (or IFD0, where some writers put it), or None."""
    value = None
    try:
        from PIL import ExifTags  # defers PIL (Pillow) off the light paths

        value = exif.get_ifd(ExifTags.IFD.Exif).get(tag)
    except Exception:  # a malformed sub-IFD must not make a readable photo unusable
        value = None
    if value is None:
        value = exif.get(tag)
    try:
        number = float(value) if value is not None else None
    except (TypeError, ValueError, ZeroDivisionError):
        return None
    return number if number is not None and math.isfinite(number) and number > 0 else None


def focal_35mm_equivalent(focal_px: float, width: int, height: int) -> int:
    """The EXIF FocalLengthIn35mmFilm a camera writes for a focal length in pixels: the same angle of
    view on a 36 x 24 mm frame (by the diagonal), in whole millimetres as phones round it."""
    return int(round(focal_px * _FILM_DIAGONAL_MM / math.hypot(width, height)))


def focal_exif_block(focal_px: float, width: int, height: int) -> bytes:
    """A JPEG APP1 payload ("Exif\\0\\0" + TIFF) holding just the 35 mm-equivalent focal length, what
    a phone photo tells about its lens (`focal_length_pixels` reads it back)."""
    from PIL import ExifTags, Image  # defers PIL (Pillow) off the light paths

    exif = Image.Exif()
    exif.get_ifd(ExifTags.IFD.Exif)[_FOCAL_LENGTH_35MM] = focal_35mm_equivalent(focal_px, width, height)
    return exif.tobytes()


def focal_length_pixels(exif: Image.Exif, stored_width: int, stored_height: int) -> Optional[float]:
    """Focal length in pixels of the stored image, or None when EXIF does not determine it.

    `stored_width`/`stored_height` are the pixel dimensions as stored (before orientation); the
    result is the same for the displayed image because focal length in pixels is isotropic here.
    """
    f35 = _exif_tag(exif, _FOCAL_LENGTH_35MM)
    if f35 is not None:
        return f35 * math.hypot(stored_width, stored_height) / _FILM_DIAGONAL_MM

    focal_mm = _exif_tag(exif, _FOCAL_LENGTH)
    plane_res = _exif_tag(exif, _FOCAL_PLANE_X_RESOLUTION)
    unit = _exif_tag(exif, _FOCAL_PLANE_RESOLUTION_UNIT)
    unit_mm = _UNIT_MM.get(int(unit)) if unit is not None else None
    if focal_mm is None or plane_res is None or unit_mm is None:
        return None
    pixels_per_mm = plane_res / unit_mm
    focal_px = focal_mm * pixels_per_mm
    # FocalPlaneXResolution refers to the sensor readout; a photo saved smaller scales with it.
    recorded_width = _exif_tag(exif, _PIXEL_X_DIMENSION)
    if recorded_width is not None and recorded_width != stored_width:
        focal_px *= stored_width / recorded_width
    return focal_px
