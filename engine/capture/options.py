"""The options `load_capture(path, **options)` accepts, in one place with their defaults."""

from __future__ import annotations

import math
from dataclasses import dataclass, fields
from pathlib import Path
from typing import Any, Optional

from ..errors import CaptureError


@dataclass(frozen=True)
class LoadOptions:
    fps: float = 2.0
    """video: frames extracted per second of video."""
    blur_fraction: float = 0.5
    """video: a frame is dropped as blurry when its sharpness (variance of the Laplacian) is below
    this fraction of the median sharpness of the extracted frames; 0 keeps every frame."""
    metric: Optional[bool] = None
    """Overrides whether the capture's poses are in metres (None: what the format says)."""
    undistort: bool = True
    """Undistort photos whose intrinsics carry lens distortion (else keep them and warn)."""
    cache_dir: Optional[Path] = None
    """Where video frames and undistorted photos go (default: the per-user cache, see cache.py)."""
    images_dir: Optional[Path] = None
    """COLMAP: the folder holding the photos when it is not `images/` beside `sparse/`."""
    verify_images: bool = True
    """Decode every photo (at 1/8 scale) at load time so corrupt files are found immediately."""

    @classmethod
    def from_kwargs(cls, options: dict[str, Any]) -> "LoadOptions":
        """Validated options; unknown names are a programming error (TypeError), bad values a CaptureError."""
        known = {f.name for f in fields(cls)}
        unknown = sorted(set(options) - known)
        if unknown:
            raise TypeError(f"unknown load_capture option(s) {', '.join(unknown)}; known: {', '.join(sorted(known))}")
        result = cls(**options)
        if not (isinstance(result.fps, (int, float)) and math.isfinite(result.fps) and result.fps > 0):
            raise CaptureError(f"fps must be a positive number of frames per second, got {result.fps!r}.")
        if not 0.0 <= result.blur_fraction < 1.0:
            raise CaptureError(f"blur_fraction must be in [0, 1), got {result.blur_fraction!r} "
                               "(0 keeps every frame; 0.5 drops frames under half the median sharpness).")
        for name in ("cache_dir", "images_dir"):
            value = getattr(result, name)
            if value is not None and not isinstance(value, Path):
                object.__setattr__(result, name, Path(value))
        return result
