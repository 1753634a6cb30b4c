"""Images as the networks and the colouring see them: resized, with intrinsics to match.

The 2D CNN was trained on 640 x 480 images, so photos of any size are resized to a long side of
`long_side` pixels (aspect ratio kept, each side rounded to a multiple of 16 so the FPN's stride-16
map upsamples exactly onto the stride-8 and stride-4 maps). Rounding makes the two axes scale by
slightly different factors, so K is scaled per axis (`engine.geometry.cameras.scale_intrinsics`).
"""

from __future__ import annotations

import cv2
import numpy as np

from ..capture import Frame, load_image

SIZE_MULTIPLE = 16


def resized_size(width: int, height: int, long_side: int, multiple: int = SIZE_MULTIPLE) -> tuple[int, int]:
    """(width, height) with the long side near `long_side`, both multiples of `multiple`."""
    scale = long_side / max(width, height)
    w = max(multiple, int(round(width * scale / multiple)) * multiple)
    h = max(multiple, int(round(height * scale / multiple)) * multiple)
    return w, h


def load_resized(frame: Frame, size: tuple[int, int]) -> np.ndarray:
    """The frame's image as uint8 (h, w, 3) RGB at `size` = (w, h).

    Downscaling uses area averaging: it is the right low-pass filter before sampling colours at
    vertex spacing, and for the CNN it matches how a camera with fewer pixels would see the scene.
    """
    image = load_image(frame.image_path)
    if image.shape[1] == size[0] and image.shape[0] == size[1]:
        return image
    shrinking = size[0] < image.shape[1]
    return cv2.resize(image, size, interpolation=cv2.INTER_AREA if shrinking else cv2.INTER_LINEAR)
