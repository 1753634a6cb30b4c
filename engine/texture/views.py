"""The photos a texture is baked from: full resolution, loaded one at a time, with a sharpness score.

A room capture can hold hundreds of 12-megapixel photos, so a view keeps only its camera and loads
its image when the bake reaches it (twice: once small for the exposure and occlusion pass, once full).
"""

from __future__ import annotations

from dataclasses import dataclass
from typing import Callable, Sequence

import cv2
import numpy as np

from ..capture import Capture, Frame
from ..capture.images import load_resized
from ..errors import VortxError

SHARPNESS_LONG_SIDE = 640  # photos are compared for blur at one size, whatever their resolution


@dataclass
class TextureView:
    """name: the photo's file name; K (3, 3) in pixels of the full image; pose (4, 4) camera-to-world
    (OpenCV axes); size (w, h) of the full image; load() -> (h, w, 3) uint8 RGB."""

    name: str
    K: np.ndarray
    pose: np.ndarray
    size: tuple[int, int]
    load: Callable[[], np.ndarray]


def _loader(frame: Frame) -> Callable[[], np.ndarray]:
    def load() -> np.ndarray:
        return load_resized(frame, (frame.width, frame.height))

    return load


def views_from_capture(capture: Capture, exclude: Sequence[str] = ()) -> list[TextureView]:
    """The posed frames of `capture` as texture views, minus the photos named in `exclude` (file names
    or stems: e.g. a held-out photo for measuring)."""
    skip = set(exclude)
    views = [TextureView(f.image_path.name, np.asarray(f.K, np.float64), np.asarray(f.pose, np.float64),
                         (int(f.width), int(f.height)), _loader(f))
             for f in capture.frames
             if f.pose is not None and f.image_path.name not in skip and f.image_path.stem not in skip]
    if not views:
        raise VortxError(f"no posed photo to bake a texture from in {capture.root}: estimate or import poses first")
    return views


def sharpness(image: np.ndarray) -> float:
    """Variance of the Laplacian of the grey image at SHARPNESS_LONG_SIDE pixels: low for blurred photos."""
    h, w = image.shape[:2]
    scale = min(1.0, SHARPNESS_LONG_SIDE / max(h, w))
    small = cv2.resize(image, (max(1, round(w * scale)), max(1, round(h * scale))), interpolation=cv2.INTER_AREA) \
        if scale < 1.0 else image
    grey = cv2.cvtColor(small, cv2.COLOR_RGB2GRAY).astype(np.float32)
    return float(cv2.Laplacian(grey, cv2.CV_32F).var())


def sharpness_weights(scores: Sequence[float]) -> np.ndarray:
    """(n,) in (0, 1]: 1 for photos at least as sharp as the median, (score / median)^2 below it, so a
    motion-blurred photo gives way wherever a sharp one sees the same surface."""
    scores = np.asarray(scores, np.float64)
    median = float(np.median(scores)) if len(scores) else 0.0
    if median <= 0:
        return np.ones(len(scores))
    return np.clip(scores / median, 0.05, 1.0) ** 2
