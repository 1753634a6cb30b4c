"""The demo's pictures: a photo beside a render of the result from that photo's camera."""

from __future__ import annotations

from pathlib import Path

import numpy as np

from .messages import DemoError


def side_by_side(photo: Path, render: Path, out: Path, label: str) -> None:
    """`photo` | `render` with a white gap, each labelled, written to `out` (same size required)."""
    import cv2  # defers cv2: OpenCV loads in a second, needed only once the renders exist

    left, right = cv2.imread(str(photo)), cv2.imread(str(render))
    if left is None or right is None:
        raise DemoError(f"cannot read {photo if left is None else render}")
    if right.shape != left.shape:  # the render is made at the photo's size; a mismatch is a bug worth seeing, not hiding
        raise DemoError(f"render {right.shape[1]}x{right.shape[0]} does not match photo {left.shape[1]}x{left.shape[0]}")
    gap = np.full((left.shape[0], 4, 3), 255, np.uint8)
    picture = np.concatenate([left, gap, right], axis=1)
    for text, x in (("photo", 6), (label, left.shape[1] + 10)):
        cv2.putText(picture, text, (x, 18), cv2.FONT_HERSHEY_SIMPLEX, 0.5, (255, 255, 255), 1, cv2.LINE_AA)
    if not cv2.imwrite(str(out), picture):
        raise DemoError(f"cannot write {out}")
